"""A reference truth for held-out comparisons, independent of the operator under test.

The held-out error of an operator, (8a)/n, compares it with a ground truth at test configurations Q. Solved from
the rest pose alone, that truth sits on whichever local minimum of problem (6) the rest pose leads to; a training
policy that finds a *lower* minimum at a training sample is then judged against the other branch. The reference
truth fixes the comparison: at every Q it is the lowest verified minimum reached from a **fixed portfolio** of
starts, the same for every policy judged against it:

* the rest pose (the rest-pose truth, :func:`defop.training.held_out`'s);
* the prolongated coarse minima: the training's start portfolio on the coarse mesh of the same shape
  (:func:`defop.training.multilevel.coarse_portfolio`, :func:`defop.geometry.coarse.prolongate`), one start per
  distinct verified coarse minimum;
* the predictions of a frozen reference operator (any callable ``op(Q) -> (m, n_vertices, d)``; a benchmark trains
  one deterministically, its predictions enter the cache key).

It replaces the rest-pose minimum only where it is lower by more than :data:`TOL` (relative) **and** is a distinct
minimum (:func:`defop.training.minima.distinct_minima`, farther than :data:`~defop.training.multilevel.DISTINCT`
of the bounding-box diagonal at some vertex): elsewhere the two truths are the same arrays. Every start runs
through the sample engine (:func:`defop.training.solves.solve`, every end point kept), and the result is cached
with its digest (:mod:`defop.training.cache`, kind ``"reference"``), so every run reads the same truth.

Near a jump of the lowest-minimum map (two minima of equal energy, not a fold), the reference truth jumps where
the energies cross; the rest-pose truth jumps where the rest pose's basin changes, and may stay on a minimum
that is no longer the lowest.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import options as opt
from ..geometry.coarse import CoarseningError
from ..operator import handle_bases as hb
from ..variational import energies as en
from . import batch, solves
from . import cache as cache_mod
from . import multilevel as ml
from .minima import distinct_minima

__all__ = ["RULE", "SOURCES", "TOL", "Reference", "pick", "portfolio_starts", "reference_truth"]

#: the reference replaces the rest-pose minimum only where it is lower by more than this, relative
TOL = 1e-6
#: where each sample's reference minimum came from (``Reference.source`` indexes this)
SOURCES = ("rest", "coarse", "operator")
#: the version of :func:`pick`'s rule and of the portfolio; part of the cache key, bump it when either changes (the
#: key already holds the library version, :data:`TOL` and :data:`~defop.training.multilevel.DISTINCT`)
RULE = 1


@dataclasses.dataclass
class Reference:
    """Both truths at m held-out configurations.

    Attributes
    ----------
    Q : (m, n, d) numpy array
    X : (m, n_vertices, d) numpy array
        The reference truth.
    converged : (m,) bool numpy array
    energy : (m,) numpy array
    X_rest : (m, n_vertices, d) numpy array
        The rest-pose truth (one solve from the rest pose per Q).
    rest_converged : (m,) bool numpy array
    rest_energy : (m,) numpy array
    source : (m,) int numpy array
        Index into :data:`SOURCES` of the start the reference minimum came from (0: the rest pose).
    digest : str
        The cache digest of the inputs (:func:`defop.training.cache.digest`).
    """

    Q: np.ndarray
    X: np.ndarray
    converged: np.ndarray
    energy: np.ndarray
    X_rest: np.ndarray
    rest_converged: np.ndarray
    rest_energy: np.ndarray
    source: np.ndarray
    digest: str = ""

    @property
    def replaced(self):
        """(m,) bool: where the reference is not the rest-pose minimum."""
        return self.source != 0

    @property
    def agree(self):
        """(m,) bool: where both truths are the same minimum."""
        return ~self.replaced


def pick(runs, diagonal, tol=TOL, distinct=ml.DISTINCT):
    """The reference's rule at one sample: the index of the end point it keeps.

    Parameters
    ----------
    runs : list of (X, energy, converged)
        Every end point, the rest-pose run **last**.
    diagonal : float
        The mesh's bounding-box diagonal.
    tol : float
        The lowest verified end point replaces the rest-pose one only when lower by more than ``tol`` × |E_rest| ...
    distinct : float
        ... and farther than ``distinct`` × ``diagonal`` from it at some vertex (a distinct minimum).

    Returns
    -------
    int
        The index of the lowest verified end point distinct from the rest pose's minimum where it is lower by more
        than the tolerance, else ``len(runs) - 1`` (the rest pose). An unverified rest-pose run gives way to the
        lowest verified end point.
    """
    X, E, ok = ([r[i] for r in runs] for i in range(3))
    rest = len(runs) - 1
    verified = [i for i in range(rest) if ok[i] and np.isfinite(E[i])]
    if not ok[rest]:
        return min(verified, key=lambda i: E[i]) if verified else rest

    def distinct_from_rest(i):
        pair = distinct_minima([X[i], X[rest]], [E[i], E[rest]], [True, True], distinct, diagonal, metric="max")
        return len(pair) == 2

    others = [i for i in verified if distinct_from_rest(i)]
    if not others:
        return rest
    low = min(others, key=lambda i: E[i])
    return low if E[low] < E[rest] - tol * abs(E[rest]) else rest


def portfolio_starts(shape, Q, energy, reference=None, coarse=True, n_jobs=None, progress=True):
    """The fixed starts of every Q but the rest pose: the prolongated coarse minima, then the reference operator's
    prediction.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    Q : (m, n, d) numpy array
    energy : str
    reference : callable, optional
        A frozen operator (``reference(Q) -> (m, n_vertices, d)``).
    coarse : bool
        Include the prolongated coarse minima (where the shape has a coarse mesh,
        :func:`defop.training.multilevel.coarse_level`; a 3D mesh has none).

    Returns
    -------
    starts : list of m lists of (n_vertices, d) arrays
    kinds : list of m lists of int
        Per start its index into :data:`SOURCES`.
    """
    m, mesh = len(Q), shape.mesh
    starts, kinds = [[] for _ in range(m)], [[] for _ in range(m)]
    lv = None
    if coarse:
        try:
            lv = ml.coarse_level(shape)
        except CoarseningError:
            lv = None
    if lv is not None:
        cands = _coarse_candidates(lv, Q, energy, n_jobs, progress)
        for k, c in enumerate(cands):
            for Xc, _ in ml.distinct_minima(c, lv.coarse.mesh.bbox_diagonal):
                X0 = lv.prolongate(Xc)
                if not (en.is_barrier(energy) and np.any(mesh.flipped(X0))):
                    starts[k].append(X0)
                    kinds[k].append(1)
    if reference is not None:
        for k, X0 in enumerate(batch.warm_starts(reference, Q, mesh, energy)):
            if X0 is not None:
                starts[k].append(X0)
                kinds[k].append(2)
    return starts, kinds


def _coarse_candidates(lv, Q, energy, n_jobs, progress):
    """Every coarse end point per Q: the training's start portfolio on the coarse mesh
    (:func:`defop.training.multilevel.coarse_portfolio`), or, for fewer Q than its linear fit needs, the engine's
    rest-pose solves there."""
    n, d = lv.coarse.n_moving, lv.coarse.mesh.V.shape[1]
    if len(Q) >= hb.basis_size("linear", n, d=d):
        return ml.coarse_portfolio(lv, Q, energy, n_jobs, progress)
    return solves.solve(lv.coarse, Q, energy, keep="all", n_jobs=n_jobs, progress=progress).runs


def _key(shape, Q, energy, reference, coarse, tol):
    """The cache key: everything that determines the reference (the operator through its predictions at Q)."""
    mesh = shape.mesh
    pred = None if reference is None else np.asarray(reference(Q), float)
    parts = [mesh.V, mesh.F, shape.handles, shape.moving, energy, solves.solver_key(shape, energy), Q]
    return cache_mod.key("reference", *parts, pred, bool(coarse), ml.coarse_constants(), float(tol), ml.DISTINCT, RULE)


def _expect(m, n, d):
    X, one = ((m, n, d), "f"), ((m,), "f")
    return {
        "X": X,
        "converged": ((m,), "b"),
        "energy": one,
        "X_rest": X,
        "rest_converged": ((m,), "b"),
        "rest_energy": one,
        "source": ((m,), "i"),
    }


def _compute(shape, Q, energy, reference, coarse, tol, n_jobs, progress):
    """Both truths, solved: the engine runs every start and the rest pose at every Q, every end point kept."""
    starts, kinds = portfolio_starts(shape, Q, energy, reference, coarse, n_jobs, progress)
    out = solves.solve(shape, Q, energy, starts=starts, rest=True, keep="all", n_jobs=n_jobs, progress=progress)
    diag = shape.mesh.bbox_diagonal
    cols = {k: [] for k in _expect(1, 1, 1)}
    for runs, kind in zip(out.runs, kinds):
        rest, i = runs[-1], pick(runs, diag, tol)
        for name, v in zip(("X_rest", "rest_energy", "rest_converged"), rest):
            cols[name].append(v)
        for name, v in zip(("X", "energy", "converged"), runs[i]):
            cols[name].append(v)
        cols["source"].append(0 if i == len(runs) - 1 else kind[i])
    arrays = {k: np.array(v) for k, v in cols.items()}
    for k in ("energy", "rest_energy"):  # an unverified run may have no finite energy; the cache holds finite arrays
        big = np.finfo(float).max
        arrays[k] = np.nan_to_num(arrays[k].astype(float), nan=big, posinf=big, neginf=-big)
    for k in ("converged", "rest_converged"):
        arrays[k] = arrays[k].astype(bool)
    arrays["source"] = arrays["source"].astype(np.int64)
    return arrays


def reference_truth(
    shape, Q, energy="sarap", reference=None, coarse=True, tol=TOL, n_jobs=None, progress=True, cache=True
):
    """The reference truth and the rest-pose truth at held-out configurations (see the module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    Q : (m, n, d) numpy array
        The held-out configurations of the moving handles.
    energy : str
    reference : callable, optional
        The frozen reference operator whose predictions are starts.
    coarse : bool
        Include the prolongated coarse minima.
    tol : float
        Relative energy below which a lower minimum does not replace the rest-pose one.
    n_jobs, progress
        As :func:`defop.training.solves.solve`.
    cache : bool
        Read and write the on-disk cache (``DEFOP_CACHE``), kind ``"reference"``.

    Returns
    -------
    Reference

    Raises
    ------
    ValueError
        Before any solve: an unknown energy, ``Q`` of the wrong shape or not finite, ``tol`` not a positive
        number, ``reference`` not callable, a ``DEFOP_CACHE`` that cannot be used.
    """
    en.check_energy(energy)
    Q = solves.check_samples(shape, Q, "Q")
    tol = opt.positive("tol", tol)
    if reference is not None and not callable(reference):
        raise ValueError(f"reference must be a trained operator (a DefOp) or None, got {type(reference).__name__}")
    store = cache_mod.open_cache(cache)
    key = _key(shape, Q, energy, reference, coarse, tol)
    n, d = shape.mesh.V.shape
    got = None if store is None else store.load("reference", key, _expect(len(Q), n, d))
    if got is not None:
        arrays = got[0]
    else:
        arrays = _compute(shape, Q, energy, reference, coarse, tol, n_jobs, progress)
        if store is not None:
            store.store("reference", key, arrays, meta={"sources": list(SOURCES), "tol": tol})
    return Reference(Q, **arrays, digest=cache_mod.digest("reference", key))
