"""Point-handle deformations that people use instead of DefOp, behind one interface: :class:`Peer`.

Each method is split into a *precompute* on the rest mesh and rest handles P, and an *evaluate* that maps
handle positions Q to deformed vertex positions X, like ``DefOp.__call__``: the closed forms (MLS, the TPS warp)
are in :mod:`.closed_forms`, the libigl methods (BBW + LBS, biharmonic coordinates, ARAP iterations) in
:mod:`.libigl`. P and Q hold *all* handles (h,d) there, fixed ones included; :func:`make_peer` wraps a method as
a :class:`Peer` that takes the moving handles only, as a DefOp does, so one harness
(:mod:`defop.analysis.compare`) times and scores them all. Triangle meshes (d = 2) and tetrahedral meshes
(d = 3) alike.
"""

from __future__ import annotations

import time

import numpy as np

from .. import options as opt
from .checks import dim_hint
from .closed_forms import (
    MAX_ALPHA,
    TPS_KERNELS,
    MLSPrecomputed,
    linear_evaluate,
    mls_evaluate,
    mls_precompute,
    tps_precompute,
)
from .libigl import ARAPIterations, bbw_precompute, biharmonic_precompute, lbs_evaluate

__all__ = [
    "KINDS",
    "MAX_ALPHA",
    "TPS_KERNELS",
    "ARAPIterations",
    "MLSPrecomputed",
    "Peer",
    "bbw_precompute",
    "biharmonic_precompute",
    "lbs_evaluate",
    "linear_evaluate",
    "make_peer",
    "make_peers",
    "mls_evaluate",
    "mls_precompute",
    "tps_precompute",
]

KINDS = ("mls-similarity", "mls-rigid", "tps", "bbw-lbs", "biharmonic", "arap")


class Peer:
    """A peer method bound to a shape: ``peer(Q)`` maps the *moving* handles to (n,d) positions, like DefOp.

    Fixed handles stay at rest. Build one with :func:`make_peer`.

    Parameters
    ----------
    name : str
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    moving : (h,) bool numpy array
    evaluate : callable
        (h,d) targets of all handles → (n,d) positions (d = ``mesh.dim``).
    precompute_time : float
        Seconds the precompute took.
    reset : callable, optional
        Forget the previous frame (stateful methods).
    """

    def __init__(self, name, mesh, handles, moving, evaluate, precompute_time, reset=None):
        self.name = name
        self.mesh = mesh
        self.handles = np.asarray(handles, dtype=np.int64)
        self.moving = np.asarray(moving, dtype=bool)
        self._evaluate = evaluate
        self.precompute_time = float(precompute_time)
        self._reset = reset

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    def __repr__(self):
        return f"Peer({self.name!r}, {self.n_vertices} vertices, {self.n_moving} moving handles)"

    def reset(self):
        """Forget the previous frame (only ARAP iterations have one)."""
        if self._reset is not None:
            self._reset()

    def __call__(self, Q):
        """Deformed vertices X (n_vertices,d) for the moving handles Q (n_moving,d), d = ``mesh.dim``.

        A batch Q (k,n_moving,d) gives X (k,n_vertices,d), evaluated frame by frame, in order; k = 0 (an empty
        batch) gives an empty (0,n_vertices,d) result, as :class:`~defop.operator.defop.DefOp` does. A Q (any
        frame of a batch) of the wrong shape or with NaN raises ValueError before any frame is evaluated: a
        stateful peer (ARAP iterations) is left as it was.
        """
        Q = opt.real_array("Q", Q)
        n, d = self.n_moving, self.mesh.dim
        if Q.shape[-2:] != (n, d) or Q.ndim not in (2, 3):
            raise ValueError(
                f"Q must have shape ({n}, {d}) or (k, {n}, {d}) for the {n} moving handles, "
                f"got {Q.shape}{dim_hint(Q, n, d)}"
            )
        if not np.isfinite(Q).all():
            where = f" (frame {int(np.argwhere(~np.isfinite(Q))[0, 0])})" if Q.ndim == 3 else ""
            raise ValueError(f"Q has NaN or infinite entries{where}")
        if Q.ndim == 3:
            X = np.empty((len(Q), self.n_vertices, d))
            for k, q in enumerate(Q):
                X[k] = self._frame(q)
            return X
        return self._frame(Q)

    def _frame(self, Q):
        """(n_vertices,d) positions for one checked (n_moving,d) Q."""
        T = self.mesh.V[self.handles].copy()
        T[self.moving] = Q
        return self._evaluate(T)


def make_peer(shape, kind, iterations=10, alpha=1.0):
    """Precompute one peer method on a shape.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
        Its mesh and handles (all of them, fixed ones included).
    kind : str
        One of ``"mls-similarity"``, ``"mls-rigid"``, ``"tps"``, ``"bbw-lbs"``, ``"biharmonic"``, ``"arap"``.
    iterations : int
        Local-global iterations per frame for ``"arap"``.
    alpha : float
        MLS weight exponent.

    Returns
    -------
    peer : Peer
        With ``precompute_time`` measured.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown peer {kind!r}; known: {', '.join(KINDS)}")
    mesh, b = shape.mesh, shape.handles
    V, P = mesh.V, mesh.V[b]
    t0 = time.perf_counter()
    reset = None
    if kind.startswith("mls"):
        pre = mls_precompute(V, P, kind.split("-")[1], alpha)
        evaluate, name = (lambda T: mls_evaluate(pre, T)), f"MLS {pre.kind}"
    elif kind == "tps":
        G = tps_precompute(V, P)
        evaluate, name = (lambda T: linear_evaluate(G, T, mesh.dim)), "TPS warp (Bookstein)"
    elif kind == "bbw-lbs":
        W = bbw_precompute(mesh, b)
        evaluate, name = (lambda T: lbs_evaluate(V, W, P, T)), "BBW + LBS"
    elif kind == "biharmonic":
        G = biharmonic_precompute(mesh, b)
        evaluate, name = (lambda T: linear_evaluate(G, T, mesh.dim)), "biharmonic coordinates"
    else:
        arap = ARAPIterations(mesh, b, iterations)
        evaluate, name, reset = arap, f"libigl ARAP, {arap.iterations} it.", arap.reset
    seconds = time.perf_counter() - t0
    return Peer(name, mesh, b, shape.moving, evaluate, seconds, reset)


def make_peers(shape, kinds=KINDS, arap_iterations=(10,)):
    """Every peer of ``kinds`` on a shape, ARAP once per entry of ``arap_iterations``.

    Returns
    -------
    peers : list of Peer
    """
    if isinstance(arap_iterations, (str, bytes)) or not hasattr(arap_iterations, "__len__") or not len(arap_iterations):
        raise ValueError(f"arap_iterations must be a non-empty list of iteration counts, got {arap_iterations!r}")
    arap_iterations = [opt.integer("arap_iterations", k, minimum=1) for k in arap_iterations]
    out = []
    for kind in kinds:
        its = arap_iterations if kind == "arap" else (10,)
        out += [make_peer(shape, kind, iterations=k) for k in its]
    return out
