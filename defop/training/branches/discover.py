"""Branch discovery: every verified minimum the starts reach at the samples Q_k (§5).

At each Q_k the multi-start of the single-valued training (:meth:`defop.variational.solver.Solver.solve_best` from
the rest pose, saddles escaped: source 0), plus the minima that **continuation** reaches: each sweep visits the
samples in an order where consecutive samples are neighbours and warm-starts every solve from the previous minimum
(a user's drag; sources 1..). The multi-starts are independent solves and the sweeps are independent of each
other: both run on the sample engine (:func:`defop.training.solves.solve` and :func:`defop.training.paths.sweeps`),
and the result is cached through :func:`defop.training.batch.load_or_compute`.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ...variational.energies import check_energy
from ...variational.solver import NotConvergedWarning, Solver
from .. import batch, paths, solves
from .. import cache as cache_mod

__all__ = ["Minima", "discover", "solve_quietly", "sweep"]


@dataclasses.dataclass
class Minima:
    """Every end point of the starts at the samples (:func:`discover`).

    Attributes
    ----------
    samples : (m, n_moving, d) numpy array
    X : (m, s, n_vertices, d) numpy array
        The end point of source s at sample k (source 0: the multi-start from the rest pose; 1..: the sweeps).
    energy : (m, s) numpy array
        E(X) (NaN where not converged).
    converged : (m, s) numpy bool array
        A verified local minimum.
    seconds : dict
        CPU seconds (``time.process_time`` of the process that solved, summed over the solves: the ratio of two
        costs does not depend on what else runs on the machine) of the rest-pose multi-start (``single``: the
        single-valued training's solves) and the sweeps, as measured when computed; ``cached`` says whether they
        were read from the cache.
    """

    samples: np.ndarray
    X: np.ndarray
    energy: np.ndarray
    converged: np.ndarray
    seconds: dict = dataclasses.field(default_factory=dict)


def solve_quietly(solver, targets, X0, start):
    """One solve of problem (6), its NotConvergedWarning silenced: (X, energy, converged)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        r = solver.solve(targets, X0=X0, start=start)
    return np.asarray(r.X), float(r.energy), bool(r.converged)


def sweep(solver, targets, X0, start="local"):
    """A continuation: each target solved warm-started from the previous minimum, the first from X0.

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    targets : sequence of (h, d) numpy arrays
        The handles' targets along the path.
    X0 : (n_vertices, d) numpy array
    start : str
        The solver's start policy for every solve.

    Returns
    -------
    X : (k, n_vertices, d) numpy array
    energy : (k,) numpy array
    converged : (k,) numpy bool array
    seconds : float
        CPU seconds of the solves (``time.process_time`` of the process that ran them).
    """
    items = paths.continuation(solver, targets, X0, solve_start=start)
    X = np.reshape([i.X for i in items], (len(targets), *np.shape(X0)))
    E = np.array([i.energy for i in items], dtype=float)
    ok = np.array([i.converged for i in items], dtype=bool)
    return X, E, ok, float(sum(i.cpu for i in items))


def _compute(shape, solver, samples, sweeps, progress, n_jobs, solver_kw):
    m, s = len(samples), 1 + len(sweeps)
    X = np.empty((m, s, shape.mesh.n_vertices, shape.mesh.V.shape[1]))
    E, conv = np.full((m, s), np.nan), np.zeros((m, s), bool)
    single = solves.solve(
        shape, samples, solver.energy, n_jobs=n_jobs, progress=progress, desc="multi-starts", solver_kw=solver_kw
    )
    X[:, 0], E[:, 0], conv[:, 0] = single.X, single.energy, single.converged
    targets = [shape.targets(q) for q in samples]
    routes = [([targets[k] for k in order[1:]], X[order[0], 0]) for order in sweeps]
    runs = paths.sweeps(solver, routes, n_jobs, progress)
    for c, (order, run) in enumerate(zip(sweeps, runs), start=1):
        first = order[0]  # each sweep starts from the multi-start's minimum there
        X[first, c], E[first, c], conv[first, c] = X[first, 0], E[first, 0], conv[first, 0]
        if len(order) > 1:
            X[order[1:], c], E[order[1:], c], conv[order[1:], c] = run.X, run.energy, run.converged
    E[~conv | ~np.isfinite(E)] = 0.0  # the cache stores finite numbers only; discover masks them out again
    seconds = [single.cpu_seconds, sum(r.cpu_seconds for r in runs)]
    return {"X": X, "energy": E, "converged": conv, "seconds": np.array(seconds, dtype=float)}


def _check(shape, samples, sweeps):
    """The samples (:func:`defop.training.solves.check_samples`) and each sweep as (m,) int64, a permutation of the
    sample indices (whole numbers: a fraction was truncated into a permutation)."""
    samples = solves.check_samples(shape, samples)
    m, out = len(samples), []
    for c, o in enumerate(sweeps):
        a = np.asarray(o)
        whole = a.dtype.kind in "iu" or (a.dtype.kind == "f" and np.array_equal(a, np.round(a)))
        if a.shape != (m,) or not whole or not np.array_equal(np.sort(a), np.arange(m)):
            raise ValueError(
                f"sweep {c} must be a permutation of the {m} sample indices 0..{m - 1}, got {a.dtype} {a.shape}"
            )
        out.append(a.astype(np.int64))
    return samples, out


def discover(shape, samples, sweeps=(), energy="sarap", cache=True, progress=False, solver_kw=None, n_jobs=None):
    """Every verified minimum the starts reach at each sample Q_k: the multi-start, then continuation sweeps.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (m, n_moving, d) numpy array
    sweeps : sequence of (m,) int arrays
        Orders of the samples (each a permutation of 0..m−1, consecutive samples neighbours, e.g.
        :func:`defop.training.branches.scan_order`); each is one continuation.
    energy : str
    cache : bool
        Store/reuse the result under ``config.cache_dir()`` (keyed by the mesh, handles, samples, sweeps and
        every solver setting).
    progress : bool
    solver_kw : dict, optional
        Passed to ``Solver``.
    n_jobs : int, optional
        Workers (:func:`defop.training.batch.parallel_map`; the result does not depend on it).

    Returns
    -------
    Minima
    """
    check_energy(energy)
    samples, sweeps = _check(shape, samples, sweeps)
    store = cache_mod.open_cache(cache)
    solver = Solver(shape.mesh, shape.handles, energy=energy, **dict(solver_kw or {}))
    key = None
    if store is not None:
        arrays = (shape.mesh.V, shape.mesh.F, np.asarray(shape.handles), np.asarray(shape.moving), samples)
        key = cache_mod.key("branch-minima-cpu", *arrays, *sweeps, energy, cache_mod.solver_settings(solver))
    m, s, n = len(samples), 1 + len(sweeps), shape.mesh.n_vertices
    d = shape.mesh.V.shape[1]
    expect = {"X": ((m, s, n, d), "f"), "energy": ((m, s), "f"), "converged": ((m, s), "b"), "seconds": ((2,), "f")}
    fresh = []

    def compute():
        fresh.append(True)
        return _compute(shape, solver, samples, sweeps, progress, n_jobs, solver_kw)

    z = batch.load_or_compute(store, "branch-minima", key, expect, compute)
    sec = z["seconds"]  # measured when computed (a cache hit returns the stored cost)
    return Minima(
        samples,
        z["X"],
        np.where(z["converged"], z["energy"], np.nan),
        z["converged"],
        {"single": float(sec[0]), "sweeps": float(sec[1]), "cached": not fresh},
    )
