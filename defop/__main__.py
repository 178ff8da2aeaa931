"""Command line: ``python -m defop page`` (your own model to a page), ``figures`` (the main job), ``cache``,
``doctor``, ``normalise`` and ``runtimes``."""

from __future__ import annotations

import argparse
import sys


def parser():
    """The command line's argument parser: the subcommands ``page``, ``figures``, ``normalise``, ``runtimes`` and
    ``doctor``."""
    parser = argparse.ArgumentParser(prog="defop", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    page_parser(sub)
    fig = sub.add_parser("figures", help="regenerate every figure into figures/ by running the notebooks")
    fig.add_argument("--only", nargs="*", help="notebook name patterns, e.g. 00_shapes or '0[12]_*'")
    fig.add_argument("--fast", action="store_true", help="CI-sized runs (DEFOP_FAST=1); outputs are not stored")
    fig.add_argument("--no-store", action="store_true", help="do not write outputs back into the notebooks")
    fig.add_argument(
        "--clean",
        action="store_true",
        help="a clean run: delete the figures and the cache first; each notebook starts from an empty cache of its "
        "own, and its time is recorded as the one from an empty cache",
    )
    fig.add_argument(
        "--timeout", type=float, default=None, help="per-cell timeout in seconds (default: defop.figures.CELL_TIMEOUT)"
    )
    fig.add_argument("--no-record", action="store_true", help="do not update figures/runtimes.json")
    fig.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="notebooks side by side, longest first, each kernel's solves in the kernel (default: one per core, at "
        "most 2; 1: one after another)",
    )
    norm = sub.add_parser(
        "normalise", help="normalise stored notebooks (metadata, widget outputs) as the main job does"
    )
    norm.add_argument("paths", nargs="*", help="notebooks (default: every notebook in notebooks/)")
    cache = sub.add_parser("cache", help="what the cache (DEFOP_CACHE) holds; --prune removes what no version reads")
    cache.add_argument("--prune", action="store_true", help="remove the entries no version of this code reads")
    cache.add_argument("--dry-run", action="store_true", help="with --prune: list them with their sizes, remove none")
    cache.add_argument(
        "--untagged", action="store_true", help="with --prune: also entries written before stamps named their versions"
    )
    sub.add_parser("runtimes", help="write figures/runtimes.json's times into the notebook headers and READMEs")
    doc = sub.add_parser("doctor", help="check (and, as root on Debian, install) what headless rendering needs")
    doc.add_argument("--no-install", action="store_true")
    doc.add_argument("--browser", action="store_true", help="also make sure chromium is there (browser test)")
    return parser


def page_parser(sub):
    """The ``page`` subcommand: :func:`defop.editor.model_page.own_model` from the command line."""
    page = sub.add_parser(
        "page",
        help="train a DefOp on your own model and write a page that drags it, and a PNG",
        description="INPUT: a polygon (.csv rows of x,y; .svg polygon, polyline or path), a picture (.png, .jpg) "
        "or a closed surface (.ply, .stl, .obj, .off). Handles are placed at the model's extremities unless given; "
        "handle 0 is fixed unless --fixed says otherwise.",
    )
    page.add_argument("input", help="the model's file")
    page.add_argument("--handles", nargs="+", help="how many handles (one integer), or handle points x,y (x,y,z)")
    page.add_argument("--fixed", nargs="+", type=int, help="the fixed handles' numbers (default: 0)")
    page.add_argument("-o", "--output", help="the page (default: INPUT's name with .html, here)")
    page.add_argument("--png", help="the picture (default: the page's name with .png)")
    page.add_argument("--dry-run", action="store_true", help="say what would be trained and how long it takes")
    page.add_argument("--fast", action="store_true", help="CI-sized settings (as DEFOP_FAST=1)")
    page.add_argument("--energy", default="sarap", help="the deformation energy (default: sarap)")
    page.add_argument("--basis", default="tps", help="the handle basis (default: tps)")
    page.add_argument("--m", type=int, default=None, help="training samples (default: train's, or the fast one)")
    page.add_argument("--vertices", type=int, default=None, help="about how many mesh vertices")


def main(argv=None):
    """Run one subcommand of ``python -m defop`` with the arguments ``argv`` (default: ``sys.argv``); the exit code."""
    args = parser().parse_args(argv)

    if args.command == "page":
        from .editor.model_page import main as page_main

        return page_main(args)
    if args.command == "figures":
        from .figures import CELL_TIMEOUT, RUNTIMES, regenerate, schedule

        report = regenerate(
            only=args.only,
            fast=args.fast,
            store=False if args.no_store else None,
            timeout=CELL_TIMEOUT if args.timeout is None else args.timeout,
            clean=args.clean,
            record=None if args.no_record else RUNTIMES,
            jobs=schedule.default_jobs() if args.jobs is None else args.jobs,
        )
        return 0 if all(r["ok"] for r in report) else 1
    elif args.command == "cache":
        return _cache(args)
    elif args.command == "normalise":
        from .figures import normalise_files, notebooks

        for path in normalise_files(args.paths or notebooks()):
            print("normalised", path)
    elif args.command == "runtimes":
        from .figures import update_stated_times

        for path in update_stated_times():
            print("updated", path)
    elif args.command == "doctor":
        from .view.render import configure_headless, ensure_system_packages

        print("defop doctor:", ensure_system_packages(install=not args.no_install))
        if args.browser:
            from .view.render import ensure_chromium

            print("defop doctor:", ensure_chromium(install=not args.no_install))
        try:
            print("defop doctor: off-screen window:", configure_headless() or "on-screen display")
        except RuntimeError as exc:
            print("defop doctor:", exc, file=sys.stderr)
            return 1
    return 0


def _cache(args):
    """``python -m defop cache``: the cache's contents, or ``--prune`` (``--dry-run``: the list only)."""
    from .config import cache_dir
    from .training import cache_admin

    try:
        folder = cache_dir()
    except ValueError as exc:
        print("defop cache:", exc, file=sys.stderr)
        return 1
    if folder is None:
        print("defop cache: the cache is off (DEFOP_CACHE=off)")
        return 0
    if not args.prune:
        print(f"defop cache: {folder}")
        for line in cache_admin.summary(cache_admin.scan(folder)):
            print(line)
        return 0
    gone = cache_admin.prune(folder, dry_run=args.dry_run, untagged=args.untagged)
    verb = "would remove" if args.dry_run else "removed"
    for e in gone:
        print(f"{verb} {e.path.name}  {e.size / 2**20:.1f} MB  ({e.status}{': ' + e.why if e.why else ''})")
    print(f"defop cache: {verb} {len(gone)} files, {sum(e.size for e in gone) / 2**20:.1f} MB from {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
