"""Build the defop book: ``python docs/build.py [OUT]`` (``make book`` → ``build/book/index.html``).

The site's sources are staged into ``<OUT>-src`` (a copy of ``docs/`` with the notebooks, the figures, the
standalone editor pages and the benchmarks README beside it, in the repository's own layout so the notebooks'
``../figures/…`` links resolve), then Sphinx writes HTML to OUT. Nothing is executed (myst-nb reads the stored
outputs) and nothing is fetched. Each build is a full one (about 15 s of CPU). Nothing is written outside OUT,
``<OUT>-src`` and ``<OUT>-doctrees``; the default OUT is the git-ignored ``build/book``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def stage(src: Path) -> Path:
    """Copy the book's sources into ``src`` (emptied first)."""
    if src.exists():
        shutil.rmtree(src)
    shutil.copytree(DOCS, src, ignore=shutil.ignore_patterns("build.py", "__pycache__", "_build"))
    (src / "notebooks").mkdir()
    for nb in sorted((ROOT / "notebooks").glob("[0-9]*.ipynb")):
        shutil.copy2(nb, src / "notebooks" / nb.name)
    shutil.copytree(ROOT / "figures", src / "figures", ignore=shutil.ignore_patterns("*.html"))
    editors = src / "_extra" / "editors"
    editors.mkdir(parents=True)
    for page in sorted((ROOT / "figures").glob("*.html")):  # the standalone editor pages, embedded live
        shutil.copy2(page, editors / page.name)
    (src / "benchmarks").mkdir()
    shutil.copy2(ROOT / "benchmarks" / "README.md", src / "benchmarks" / "README.md")
    return src


def build(out: Path, strict: bool = False, quiet: bool = True) -> int:
    """Stage the sources next to ``out`` and run Sphinx's HTML builder; returns Sphinx's exit status."""
    from sphinx.cmd.build import build_main

    out = Path(out).resolve()
    src = stage(out.with_name(out.name + "-src"))
    doctrees = out.with_name(out.name + "-doctrees")
    # always a full build: an unchanged page can show what changed elsewhere (the API tables show the
    # docstrings' first lines), and no page of an earlier build survives (a renamed lesson, a removed module)
    for folder in (out, doctrees):
        if folder.exists():
            shutil.rmtree(folder)
    os.environ["DEFOP_BOOK_ROOT"] = str(ROOT)
    args = ["-b", "html", "-d", str(doctrees), "-j", "1", "--keep-going"]
    args += ["-W"] if strict else []
    args += ["-q"] if quiet else []
    return build_main([*args, str(src), str(out)])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(ROOT / "build" / "book"), help="output folder")
    parser.add_argument("--strict", action="store_true", help="turn Sphinx warnings into errors")
    parser.add_argument("--verbose", action="store_true", help="Sphinx's progress messages")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rc = build(Path(args.out), strict=args.strict, quiet=not args.verbose)
    print(f"docs/build.py: {args.out}/index.html in {time.perf_counter() - start:.1f} s (sphinx exit {rc})")
    return rc


if __name__ == "__main__":
    sys.exit(main())
