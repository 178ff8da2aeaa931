"""Your own model to a page in one call: read a polygon, picture or surface file, place handles, train, write the
page and a picture (``python -m defop page INPUT``, :func:`own_model`).

The stages: :func:`defop.scene.own_input.load_model` reads the file and places the handles (pure);
:func:`plan` says what will be trained and how long it should take (one measured solve); :func:`own_model` trains
with :func:`defop.training.train`'s defaults (its tqdm bars show each stage's ETA; the plan gives the overall one),
writes the page (:func:`defop.editor.export.to_html`) and a PNG of the rest pose beside one deformed pose
(:func:`picture`). Bad input is refused before anything is trained or written.
"""

from __future__ import annotations

import dataclasses
import time
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .. import config
from .. import options as opt
from ..scene.own_input import accepted_kinds, input_kind, load_model
from ..training import bootstrap, sampling
from .export import to_html

__all__ = ["FAST", "LONG", "OwnModel", "Plan", "own_model", "picture", "plan"]

#: fast mode (``DEFOP_FAST=1`` or ``fast=True``): mesh vertices by dimension, samples above the handle basis'
#: minimum (:func:`defop.training.min_samples`) and solve rounds; a CI-sized check that the path works end to end
FAST = {"n_vertices": {2: 300, 3: 300}, "extra_samples": 2, "rounds": 1}

#: an estimate above this many seconds is announced with a warning and the options that shorten it
LONG = 300.0


@dataclasses.dataclass
class Plan:
    """What :func:`own_model` trains, and the estimate of how long it takes (:func:`plan`).

    Attributes
    ----------
    lines : list of str
        The model, its handles, the training settings and the estimate, as printed.
    m, rounds : int
    seconds : float
        The estimated wall time of the training from an empty cache.
    """

    lines: list
    m: int
    rounds: int
    seconds: float


@dataclasses.dataclass
class OwnModel:
    """What :func:`own_model` made: the model, the operator and the files (None in a dry run)."""

    own: object
    plan: Plan
    op: object = None
    record: object = None
    page: Path | None = None
    png: Path | None = None

    @property
    def shape(self):
        """The :class:`defop.scene.shapes.Shape`."""
        return self.own.shape


def _one_solve_seconds(shape, energy, seed):
    """Wall seconds of one solve of problem (6) at a sample of the shape's regions, from the rest pose, on 1 job:
    the faster of two solves (the first also compiles and loads what the solver needs)."""
    Q = sampling.sample_shape(shape, 2, np.random.default_rng(seed))
    times = []
    for q in Q:
        start = time.perf_counter()
        bootstrap.solve_samples(shape, q[None], energy, n_jobs=1, progress=False)
        times.append(time.perf_counter() - start)
    return min(times)


def plan(own, energy="sarap", basis="tps", m=None, rounds=None, n_jobs=None, seed=0):
    """What will be trained on ``own`` and how long it takes, from one measured solve.

    The estimate: one solve at a sample of the shape's regions, from the rest pose on one core, is timed (t, the
    faster of two, since the first also compiles); the training's start portfolio (:mod:`defop.training.portfolios`)
    runs about 2 starts per sample in its first round (the rest pose and a linear fit's prediction) and 1 in each
    later round, in parallel on ``n_jobs`` workers, so the wall time is about t × m × (rounds + 1) / min(n_jobs, m).
    The starts from a fit's prediction are usually cheaper than the timed one from the rest pose, and a warm cache
    makes training a load: it is an upper estimate for an empty cache.

    Parameters
    ----------
    own : defop.scene.own_input.OwnShape
    energy, basis, m, rounds, n_jobs, seed
        As in :func:`defop.training.train` (m None: its default).

    Returns
    -------
    plan : Plan
    """
    shape = own.shape
    d = shape.mesh.dim
    default_m, default_rounds = bootstrap.defaults(own.shape.mesh.dim)  # train's defaults in this dimension
    m = default_m if m is None else opt.integer("m", m, minimum=1)
    rounds = opt.integer("rounds", default_rounds if rounds is None else rounds, minimum=1)
    jobs = opt.n_jobs(n_jobs)
    jobs = config.n_jobs() if jobs is None else jobs
    jobs = max(1, opt.cpu_count() + 1 + jobs if jobs < 0 else jobs)  # joblib's -1: every core
    t = _one_solve_seconds(shape, energy, seed)
    seconds = t * m * (rounds + 1) / min(jobs, m)
    mesh = shape.mesh
    what = "triangles" if d == 2 else "tetrahedra"
    lines = [
        f"model: {own.kind} file {own.path}, {d}D, {mesh.n_vertices} vertices, {mesh.n_faces} {what}",
        f"handles ({'placed automatically' if own.automatic else 'given'}): {len(own.groups)}, "
        f"{len(own.fixed)} fixed; {shape.n_moving} moving vertices",
        *("  " + line for line in own.handle_lines()),
        f"training: energy {energy}, handle basis {basis}, m = {m} samples, {rounds} round(s), {jobs} worker(s)",
        f"estimate: about {_duration(seconds)} from an empty cache (one solve took {t:.2f} s; "
        f"× {m} samples × {rounds + 1} starts / {min(jobs, m)} workers)",
    ]
    if seconds > LONG:
        lines.append(
            f"warning: a long training (more than {_duration(LONG)}); --vertices, --m or --handles make it shorter, "
            "--fast much shorter (and coarser)"
        )
    return Plan(lines, m, rounds, seconds)


def _duration(seconds):
    """``"42 s"`` or ``"3 min 20 s"``."""
    s = int(round(seconds))
    return f"{s} s" if s < 60 else f"{s // 60} min {s % 60} s"


def picture(shape, op, Q):
    """The rest pose beside the deformed pose op(Q), as an (H,W,3) or (H,W,4) uint8 image.

    2D: matplotlib (:func:`defop.view.draw.plot_shape` and :func:`~defop.view.draw.plot_deformation`); 3D: PyVista
    off-screen (:func:`defop.view.render.render_panels`, the user's surface when the shape embeds one).
    """
    X = op(Q)
    if shape.mesh.dim == 3:
        from ..view import render

        titles = [f"{shape.name}: rest pose", f"{shape.name}: a deformed pose"]
        return render.render_panels(
            shape.mesh, [shape.mesh.V, X], titles, handles=shape.handles, moving=shape.moving, surface=shape.surface
        )
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..view import draw

    fig = Figure(figsize=(10, 5), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax0, ax1 = fig.subplots(1, 2)
    draw.plot_shape(ax0, shape, title=f"{shape.name}: rest pose")
    draw.plot_deformation(ax1, shape, X, title=f"{shape.name}: a deformed pose")
    for ax in (ax0, ax1):
        ax.set_aspect("equal")
        ax.set_axis_off()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba()).copy()


def _outputs(path, out, png):
    """(page path, picture path) checked before any work: default ``<input name>.html`` and ``.png`` here."""
    out = Path(f"{path.stem}.html") if out is None else Path(out)
    png = out.with_suffix(".png") if png is None else Path(png)
    for what, p in (("page", out), ("picture", png)):
        if p.suffix.lower() != (".html" if what == "page" else ".png"):
            raise ValueError(f"{what} {p}: the name must end in {'.html' if what == 'page' else '.png'}")
        if not p.parent.resolve().is_dir():
            raise ValueError(f"{what} {p}: the folder {p.parent} does not exist")
    if out.resolve() == png.resolve() or path.resolve() in (out.resolve(), png.resolve()):
        raise ValueError(f"page {out}, picture {png} and input {path} must be three different files")
    return out, png


def _posed(record, shape):
    """A deformed pose to show: the training sample that moves the handles most."""
    Q = record.samples
    move = np.abs(Q - shape.P_moving[None]).reshape(len(Q), -1).sum(axis=1)
    return Q[int(np.argmax(move))]


def own_model(
    input,
    handles=None,
    fixed=None,
    out=None,
    png=None,
    dry_run=False,
    fast=None,
    energy="sarap",
    basis="tps",
    m=None,
    n_vertices=None,
    n_jobs=None,
    seed=0,
    progress=True,
    echo=print,
):
    """From your model's file to a page that drags it, in one call (what ``python -m defop page`` runs).

    Parameters
    ----------
    input : str or pathlib.Path
        A polygon (``.csv`` rows of x,y; ``.svg`` polygon, polyline or path), a picture (``.png``, ``.jpg``) or a
        closed surface (``.ply``, ``.stl``, ``.obj``, ``.off``): :data:`defop.scene.own_input.INPUT_KINDS`.
    handles : int or (h,d) array_like, optional
        How many handles to place automatically, or the handle points (:func:`defop.scene.own_input.load_model`).
    fixed : int or sequence of int, optional
        The fixed handles (default: handle 0).
    out, png : str or pathlib.Path, optional
        The page (default ``<input name>.html`` in the current folder) and the picture (default: the page's
        name ending in ``.png``).
    dry_run : bool
        Only read the model and say what would be trained and how long it takes (:func:`plan`); nothing is trained
        or written.
    fast : bool, optional
        CI-sized settings (:data:`FAST`); default: ``DEFOP_FAST``.
    energy, basis, m, n_jobs, seed
        As in :func:`defop.training.train` (m None: its default, or the fast one).
    n_vertices : int, optional
        About how many mesh vertices (default: the reader's, or the fast one).
    progress : bool
        The training's progress bars.
    echo : callable
        Called with each line of the report (``print``; ``None`` for silence).

    Returns
    -------
    result : OwnModel
        ``result.shape``, ``result.op``, ``result.page``, ``result.png`` (op and paths None in a dry run).

    Raises
    ------
    ValueError
        Before anything is trained or written: the input (see :func:`~defop.scene.own_input.load_model`), the
        output names, or a training option.
    """
    echo = echo or (lambda *a: None)
    path, kind = input_kind(input)
    out, png = (None, None) if dry_run else _outputs(path, out, png)
    fast = config.fast_mode() if fast is None else bool(fast)
    d = 3 if kind == "surface" else 2
    if fast and n_vertices is None:
        n_vertices = FAST["n_vertices"][d]
    own = load_model(path, handles, fixed, n_vertices)
    rounds = FAST["rounds"] if fast else bootstrap.defaults(d)[1]
    if fast and m is None:
        m = bootstrap.min_samples(basis, own.shape.n_moving, d) + FAST["extra_samples"]
    bootstrap.check_train_options(own.shape, basis, m, "hat", 100, seed, None, n_jobs, rounds)
    the_plan = plan(own, energy, basis, m, rounds, n_jobs, seed)
    for line in the_plan.lines:
        echo(line)
    result = OwnModel(own, the_plan)
    if dry_run:
        echo("dry run: nothing trained or written")
        return result
    return _train_and_write(result, out, png, energy, basis, n_jobs, seed, progress, echo)


def _train_and_write(result, out, png, energy, basis, n_jobs, seed, progress, echo):
    """The training, the page and the picture of :func:`own_model`, each announced."""
    shape, the_plan = result.own.shape, result.plan
    done = datetime.now() + timedelta(seconds=the_plan.seconds)
    echo(f"training (about {_duration(the_plan.seconds)}, until about {done:%H:%M:%S}) ...")
    start = time.perf_counter()
    m, rounds = the_plan.m, the_plan.rounds
    op, record = bootstrap.train(shape, energy, basis, m=m, seed=seed, n_jobs=n_jobs, progress=progress, rounds=rounds)
    cached = "" if record.cache == "none" else f", {record.cache} from the cache"
    echo(f"trained in {_duration(time.perf_counter() - start)}{cached}")
    result.op, result.record = op, record
    image = _png_bytes(picture(shape, op, _posed(record, shape)))  # before any file is written
    image_kw = {"image": result.own.path} if result.own.kind == "picture" else {}  # the picture, placed by to_html
    result.page = to_html(op, out, shape=shape, title=f"{shape.name}: drag the handles", **image_kw)
    echo(f"wrote the page {result.page} ({result.page.stat().st_size / 1e6:.1f} MB): open it in a browser")
    opt.write_atomic(png, image, "png")
    result.png = png
    echo(f"wrote the picture {png} (the rest pose and a deformed pose)")
    return result


def _png_bytes(image):
    """The PNG encoding of an (H,W,3) or (H,W,4) uint8 image."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def main(args):
    """``python -m defop page`` with its parsed arguments: 0, or 2 after printing the error (nothing written)."""
    import sys

    try:
        handles = _parse_handles(args.handles)
        own_model(
            args.input,
            handles=handles,
            fixed=args.fixed,
            out=args.output,
            png=args.png,
            dry_run=args.dry_run,
            fast=True if args.fast else None,
            energy=args.energy,
            basis=args.basis,
            m=args.m,
            n_vertices=args.vertices,
        )
    except ValueError as exc:
        print(f"defop page: error: {exc}", file=sys.stderr)
        if "unknown kind" not in str(exc):
            print(f"defop page: accepted inputs: {accepted_kinds()}", file=sys.stderr)
        return 2
    return 0


def _parse_handles(values):
    """``--handles``: None, one integer (a count), or points ``x,y`` (``x,y,z``) each; ValueError otherwise."""
    if not values:
        return None
    if len(values) == 1 and values[0].strip().lstrip("+").isdigit():
        return int(values[0])
    points = []
    for v in values:
        try:
            points.append([float(x) for x in v.split(",")])
        except ValueError:
            raise ValueError(f"--handles: {v!r} is not a point x,y (or x,y,z), nor a count") from None
    if len({len(p) for p in points}) != 1:
        raise ValueError(f"--handles: the points {' '.join(values)} do not all have the same number of coordinates")
    return np.array(points)
