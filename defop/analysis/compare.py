"""One harness to time and score DefOp and its peers (:mod:`defop.rivals.peers`) against a ground truth.

Every method is a callable ``method(Q) → X`` on the moving handles (a :class:`~defop.operator.DefOp` or a
:class:`~defop.rivals.peers.Peer`). :func:`score` runs it once over the held-out frames, in order (so ARAP
iterations warm-start from the previous frame), timing each frame with BLAS pinned to one thread, and
scores the frames with the paper's Fig. 8 metric (:func:`defop.analysis.metrics.approximation_error`).

The same harness scores triangle meshes (d = 2) and tetrahedral meshes (d = 3), reading d from the shape's
mesh; a frame's inverted elements are the ones :meth:`defop.geometry.mesh.Mesh.flipped` counts (signed volume
≤ 0): flipped triangles in 2D, inverted tetrahedra in 3D.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import options as opt
from . import metrics

COLUMNS = (
    "method",
    "(8a)/n",
    "worst/diag",
    "flips/frame",
    "frames flipped",
    "handle err",
    "precompute",
    "frame median",
    "frame best",
)
#: the 3D headers of the inverted-element columns
INVERTED_HEADER = {"flips/frame": "inverted tets/frame", "frames flipped": "frames inverted"}


@dataclasses.dataclass
class Score:
    """How one method did on k held-out frames.

    Attributes
    ----------
    name : str
    error : float
        (8a)/n, the paper's Fig. 8 metric: (1/n) Σ_k ‖D^E(·,Q_k) − D(·,Q_k)‖²_{L²}.
    worst : float
        The largest vertex error over all frames, divided by the bounding-box diagonal.
    flips_per_frame : float
        Mean number of inverted elements per frame (signed volume ≤ 0): flipped triangles in 2D, inverted
        tetrahedra in 3D.
    frames_flipped : int
        Frames with at least one inverted element.
    handle_error : float
        Largest distance of a handle vertex from its target.
    precompute : float
        Seconds (NaN when not given).
    frame_median, frame_best : float
        Seconds per frame: CPU time of the calling thread, single-threaded BLAS (see :func:`run_frames`).
    n_frames : int
    dim : int
        d of the mesh: 2 (triangles) or 3 (tetrahedra); names the inverted-element column.
    """

    name: str
    error: float
    worst: float
    flips_per_frame: float
    frames_flipped: int
    handle_error: float
    precompute: float
    frame_median: float
    frame_best: float
    n_frames: int
    dim: int = 2

    @property
    def inverted_per_frame(self) -> float:
        """:attr:`flips_per_frame`, by its 3D name: inverted tetrahedra (or flipped triangles) per frame."""
        return self.flips_per_frame

    def row(self):
        """The table row as strings (see :data:`COLUMNS`)."""
        return (
            self.name,
            f"{self.error:.2e}",
            f"{self.worst:.3f}",
            f"{self.flips_per_frame:.1f}",
            f"{self.frames_flipped}/{self.n_frames}",
            f"{self.handle_error:.1e}",
            _seconds(self.precompute),
            _seconds(self.frame_median),
            _seconds(self.frame_best),
        )


def _seconds(s):
    if not np.isfinite(s):
        return "-"
    for unit, f in (("s", 1.0), ("ms", 1e3), ("µs", 1e6)):
        if s * f >= 1.0 or unit == "µs":
            return f"{s * f:.3g} {unit}"


def run_frames(method, Q):
    """Evaluate a method frame by frame, in order, timing each frame with single-threaded BLAS.

    A frame's time is the CPU time of the calling thread (:func:`time.thread_time`): other jobs on a shared
    machine preempt the process but do not add to it, so ratios between methods hold under load. With BLAS
    pinned to one thread this is the frame's single-thread cost; a method that ran work on other threads
    would be under-counted (none of :mod:`defop.rivals.peers` does with one BLAS thread).

    One untimed warm-up frame runs first (at ``Q[0]``); a method with ``reset`` is reset after it, so the
    frames see the same history with or without the warm-up.

    Parameters
    ----------
    method : callable
        (n_moving,d) → (n_vertices,d).
    Q : (k,n_moving,d) numpy array
        d = 2 or 3.

    Returns
    -------
    X : (k,n_vertices,d) numpy array
    seconds : (k,) numpy array
    """
    from threadpoolctl import threadpool_limits

    Q = opt.real_array("Q", Q)
    if Q.ndim != 3 or Q.shape[-1] not in (2, 3) or len(Q) == 0:
        raise ValueError(f"Q must be a batch of shape (k, n_moving, d), d = 2 or 3, with k >= 1, got {Q.shape}")
    out, seconds = [], np.empty(len(Q))
    with threadpool_limits(1):
        method(Q[0])
        if hasattr(method, "reset"):
            method.reset()
        for i, q in enumerate(Q):
            t0 = time.thread_time()
            X = method(q)
            seconds[i] = time.thread_time() - t0
            out.append(X)
    return np.asarray(out, dtype=float), seconds


class _Frames:
    """Frames already computed, shaped like a DefOp for :mod:`defop.analysis.metrics` (which calls ``op(samples)``)."""

    def __init__(self, mesh, X):
        self.mesh, self.X = mesh, X
        self.n_vertices = mesh.n_vertices

    def __call__(self, Q):
        return self.X


def score(method, shape, Q, X_true, name=None, precompute=None):
    """Score one method on held-out frames against their ground truth.

    Parameters
    ----------
    method : callable
        A DefOp or a :class:`~defop.rivals.peers.Peer` (n_moving,d) → (n_vertices,d).
    shape : defop.scene.shapes.Shape
        The shape both were built on (mesh and handles); d = ``shape.mesh.dim``.
    Q : (k,n_moving,d) numpy array
    X_true : (k,n_vertices,d) numpy array
    name : str, optional
        Default: ``method.name`` or its repr.
    precompute : float, optional
        Seconds; default ``method.precompute_time`` when it has one.

    Returns
    -------
    score : Score
    X : (k,n_vertices,d) numpy array
        The method's frames.
    """
    Q = opt.real_array("Q", Q)
    n, d = shape.n_moving, shape.mesh.dim
    if Q.ndim != 3 or Q.shape[1:] != (n, d) or len(Q) == 0:
        raise ValueError(f"Q must be a batch of shape (k, {n}, {d}) with k >= 1 (the moving handles), got {Q.shape}")
    X_true = opt.real_array("X_true", X_true)
    if precompute is not None and not (
        isinstance(precompute, (int, float, np.number))
        and np.isfinite(precompute)
        and precompute >= 0
        and not isinstance(precompute, (bool, np.bool_))
    ):
        raise ValueError(f"precompute must be None or seconds, a finite number >= 0, got {precompute!r}")
    if X_true.shape != (len(Q), shape.mesh.n_vertices, d):
        raise ValueError(f"X_true must have shape ({len(Q)}, {shape.mesh.n_vertices}, {d}), got {X_true.shape}")
    X, seconds = run_frames(method, Q)
    if not np.isfinite(X).all():
        raise ValueError(f"{name or method!r} returned NaN or infinite positions")
    mesh = shape.mesh
    flips = np.array([np.count_nonzero(mesh.flipped(x)) for x in X])
    targets = np.stack([shape.targets(q) for q in Q])
    if precompute is None:
        precompute = getattr(method, "precompute_time", np.nan)
    s = Score(
        name=name or getattr(method, "name", repr(method)),
        error=metrics.approximation_error(_Frames(mesh, X), Q, X_true),
        worst=float(np.linalg.norm(X - X_true, axis=-1).max() / mesh.bbox_diagonal),
        flips_per_frame=float(flips.mean()),
        frames_flipped=int(np.count_nonzero(flips)),
        handle_error=float(np.linalg.norm(X[:, shape.handles] - targets, axis=-1).max()),
        precompute=float(precompute),
        frame_median=float(np.median(seconds)),
        frame_best=float(seconds.min()),
        n_frames=len(Q),
        dim=d,
    )
    return s, X


def pareto_front(cost, error):
    """Indices of the methods no other method beats in both cost and error, by increasing cost.

    Parameters
    ----------
    cost, error : (m,) numpy array

    Returns
    -------
    front : list of int
    """
    cost, error = np.asarray(cost, float), np.asarray(error, float)
    if cost.ndim != 1 or cost.shape != error.shape:
        raise ValueError(f"cost and error must be two (m,) arrays of one length, got {cost.shape} and {error.shape}")
    if not (np.isfinite(cost).all() and np.isfinite(error).all()):  # a NaN method was silently left off the front
        raise ValueError("cost and error must be finite: a method without a measured cost or error has no place")
    front, best = [], np.inf
    for i in np.lexsort((error, cost)):
        if error[i] < best:
            front.append(int(i))
            best = error[i]
    return front


def markdown_table(scores):
    """The scores as a Markdown table (one row per method, :data:`COLUMNS`).

    On tetrahedral meshes the flips column is headed "inverted tets/frame" (the same count: signed volume ≤ 0).

    Returns
    -------
    text : str
    """
    columns = [INVERTED_HEADER.get(c, c) for c in COLUMNS] if any(s.dim == 3 for s in scores) else COLUMNS
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(s.row()) + " |" for s in scores]
    return "\n".join(lines)


def _per_method(name, values, n):
    """None (the defaults) or a list of one entry per method: a shorter list silently dropped methods."""
    if values is None:
        return [None] * n
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or len(values) != n:
        got = f"{len(values)} entries" if hasattr(values, "__len__") else repr(values)
        raise ValueError(f"{name} must be None or a list of one entry per method ({n}), got {got}")
    return list(values)


def score_all(methods, shape, Q, X_true, names=None, precompute=None):
    """:func:`score` for several methods on the same frames.

    Parameters
    ----------
    methods : list of callable
    shape : defop.scene.shapes.Shape
    Q : (k,n_moving,d) numpy array
    X_true : (k,n_vertices,d) numpy array
    names, precompute : list, optional
        Per method; None entries use the defaults of :func:`score`.

    Returns
    -------
    scores : list of Score
    frames : dict of str -> (k,n_vertices,d) numpy array
        Each method's frames, by name.
    """
    methods = list(methods)
    names = _per_method("names", names, len(methods))
    precompute = _per_method("precompute", precompute, len(methods))
    scores, frames = [], {}
    for method, name, pre in zip(methods, names, precompute, strict=True):
        s, X = score(method, shape, Q, X_true, name=name, precompute=pre)
        scores.append(s)
        frames[s.name] = X
    return scores, frames
