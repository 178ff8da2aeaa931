"""Training a DefOp by bootstrapping (§3.3): sample, solve the variational problem, fit.

Stages, each timed in the :class:`TrainingRecord`:

1. **bootstrap**: the first 2n + 1 samples (n moving handles) are solved from the rest pose and a
   *linear* operator is fitted to them;
2. **solve**: every other sample is solved globally (:meth:`defop.solve.Solver.solve_best`): from the
   rest pose and from that linear operator's prediction (skipped when it flips a triangle under a
   barrier energy), keeping the lowest verified minimum; ``rounds > 1`` re-solves every sample from its
   current solution and the prediction of a smooth fit, keeping the lower;
3. **fit**: the final basis (problem 8).

Sample solves run in parallel with joblib on every core by default (``DEFOP_N_JOBS``), through
whatever joblib backend is active, so ``with joblib.parallel_backend("dask"):`` runs them on a Dask
cluster. Ground truths and trained operators are cached on disk (``DEFOP_CACHE``), keyed by a hash of
everything that determines them, so notebooks and figures never retrain.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
import warnings

import numpy as np

from . import config
from . import energies as en
from .fit import fit
from .operator import DefOp
from .sampling import sample_shape
from .solve import NotConvergedWarning, Solver

DEFAULT_M = 200


@dataclasses.dataclass
class TrainingRecord:
    """What training did.

    Attributes
    ----------
    samples : (m,n,2) numpy array
        The training configurations Q_k (rest pose excluded).
    X : (m,n_vertices,2) numpy array or None
        Their ground-truth deformations.
    converged : (m,) bool numpy array or None
    stage_times : dict of str -> float
        Seconds per stage (``bootstrap``, ``solve``, ``fit``, ``fold``).
    cache : str
        ``"operator"`` (loaded trained operator), ``"ground truth"`` (loaded samples, refitted) or ``"none"``.
    params : dict
    """

    samples: np.ndarray
    X: np.ndarray | None
    converged: np.ndarray | None
    stage_times: dict
    cache: str
    params: dict

    @property
    def total_time(self) -> float:
        return float(sum(self.stage_times.values()))


def _hash(*parts):
    h = hashlib.sha1()
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(np.ascontiguousarray(p).tobytes())
            h.update(str(p.shape).encode())
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
    return h.hexdigest()[:20]


def _solve_chunk(solver, targets, starts, rest=True):
    """:meth:`Solver.solve_best` per sample: its starts (None, one map or a list of maps) and the rest pose."""
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for T, X0 in zip(targets, starts):
            extra = [] if X0 is None else list(X0) if isinstance(X0, (list, tuple)) else [X0]
            r = solver.solve_best(T, starts=extra, rest=rest)
            out.append((r.X, r.converged))
    return out


def _progress(total, desc, enabled):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, leave=False)


def solve_samples(shape, samples, energy="sarap", X0=None, n_jobs=None, progress=True, desc="solving", rest=True):
    """Solve problem (6) at every sample, in parallel: the lowest verified minimum over the starts
    (:meth:`defop.solve.Solver.solve_best`).

    Parameters
    ----------
    shape : defop.shapes.Shape
    samples : (m,n,2) numpy array
    energy : str
    X0 : (m,n_vertices,2) numpy array or list, optional
        Extra starts per sample: None, one (n_vertices,2) map, or a list of maps.
    n_jobs : int, optional
        Workers (default ``dop.config.n_jobs()``: all cores); 1 solves in this process.
    progress : bool
        A tqdm progress bar.
    rest : bool
        Also solve from the rest pose (through flip-free continuation).

    Returns
    -------
    X : (m,n_vertices,2) numpy array
    converged : (m,) bool numpy array
        Verified local minimum (see :meth:`defop.solve.Solver.verify`).
    """
    from joblib import Parallel, delayed

    samples = np.asarray(samples, float)
    m = len(samples)
    targets = [shape.targets(q) for q in samples]
    starts = list(X0) if X0 is not None else [None] * m
    solver = Solver(shape.mesh, shape.handles, energy)
    n_jobs = config.n_jobs() if n_jobs is None else n_jobs
    bar = _progress(m, desc, progress)
    results = []
    if n_jobs == 1 or m <= 2:
        for i in range(m):
            results += _solve_chunk(solver, targets[i : i + 1], starts[i : i + 1], rest)
            if bar:
                bar.update(1)
    else:
        from joblib import effective_n_jobs

        n_chunks = min(m, 4 * max(1, effective_n_jobs(n_jobs)))
        bounds = np.linspace(0, m, n_chunks + 1).astype(int)
        chunks = [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        gen = Parallel(n_jobs=n_jobs, return_as="generator")(
            delayed(_solve_chunk)(solver, targets[a:b], starts[a:b], rest) for a, b in chunks
        )
        for (a, b), res in zip(chunks, gen):
            results += res
            if bar:
                bar.update(b - a)
    if bar:
        bar.close()
    X = np.array([r[0] for r in results])
    conv = np.array([r[1] for r in results], dtype=bool)
    return X, conv


def sample_ground_truth(shape, samples, energy="sarap", X0=None, n_jobs=None, progress=True, cache=True):
    """:func:`solve_samples` with an on-disk cache keyed by mesh, handles, energy and samples.

    Returns
    -------
    X : (m,n_vertices,2) numpy array
    converged : (m,) bool numpy array
    """
    samples = np.asarray(samples, float)
    key = _hash("gt", shape.mesh.V, shape.mesh.F, shape.handles, shape.moving, energy, samples)
    folder = config.cache_dir() if cache else None
    path = None if folder is None else folder / f"gt-{key}.npz"
    if path is not None and path.exists():
        with np.load(path) as z:
            return z["X"], z["converged"]
    X, conv = solve_samples(shape, samples, energy, X0, n_jobs, progress)
    if path is not None:
        np.savez(path, X=X, converged=conv)
    return X, conv


def held_out(shape, energy, m, seed, like=None, n_jobs=None, progress=True, cache=True):
    """Held-out test samples and their ground truth, solved like the training samples.

    Each test configuration is solved globally (:meth:`defop.solve.Solver.solve_best`): from the rest
    pose and, when ``like`` is given, also from ``like(Q)``; the lowest verified minimum is kept (the rule
    of the training solves), so the test set sits on the same branches as the training set.

    Parameters
    ----------
    shape : defop.shapes.Shape
    energy : str
    m : int
        Number of test samples.
    seed : int
        Seeds their sampling (use one the training did not).
    like : defop.operator.DefOp, optional
        An operator whose predictions warm-start the second solve.

    Returns
    -------
    Q : (m,n,2) numpy array
    X : (m,n_vertices,2) numpy array
    converged : (m,) bool numpy array
    """
    Q = sample_shape(shape, m, np.random.default_rng(seed))
    X, conv = sample_ground_truth(shape, Q, energy, None, n_jobs, progress, cache)
    if like is not None:
        # the rest-pose solutions (cached) and like's predictions as the starts of one multi-start solve
        starts = [[x, w] for x, w in zip(X, _warm_starts(like, Q, shape.mesh, energy))]
        X, conv = solve_samples(shape, Q, energy, starts, n_jobs, progress, desc="warm test solves", rest=False)
    return Q, X, conv


def _warm_starts(op, samples, mesh, energy):
    from .operator import ExtrapolationWarning

    starts = []
    with warnings.catch_warnings():  # a warm start may extrapolate: the solver corrects it
        warnings.simplefilter("ignore", ExtrapolationWarning)
        predictions = op(samples)
    for X in predictions:
        starts.append(None if en.is_barrier(energy) and np.any(mesh.flipped(X)) else X)
    return starts


def train(
    shape,
    energy="sarap",
    basis="tps",
    m=None,
    spatial="hat",
    k=100,
    seed=0,
    samples=None,
    n_jobs=None,
    cache=True,
    progress=True,
    rounds=2,
):
    """Train a DefOp for a shape: sample, bootstrap, solve, fit (§3.3).

    Parameters
    ----------
    shape : defop.shapes.Shape
    energy : str
        ``"arap"``, ``"sarap"`` or ``"isometric"``.
    basis : str
        Handle basis Ψ: ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"``.
    m : int, optional
        Number of samples Q_k (default 200; ignored when ``samples`` is given).
    spatial : str
        Φ: ``"hat"`` or ``"reduced"``.
    k : int
        Size of the reduced Φ.
    seed : int
        Seeds the sampling of Q_k.
    samples : (m,n,2) numpy array, optional
        Use these configurations instead of sampling.
    n_jobs : int, optional
        Parallel solves (default: every core).
    cache : bool
        Read and write the on-disk cache.
    progress : bool
        tqdm progress bars.
    rounds : int
        How many times the solve stage runs. Rounds after the first re-solve every sample warm-started
        from a smooth (quadratic, or linear) fit of the current samples and keep whichever solution has
        the lower energy: this moves samples that landed in a higher local minimum (measured on the bar:
        1 of 17 samples at 1.5x the energy of the branch its neighbours are on) back onto the branch.

    Returns
    -------
    defop : defop.operator.DefOp
    record : TrainingRecord
    """
    en.check_energy(energy)
    if samples is None:
        m = DEFAULT_M if m is None else m
        samples = sample_shape(shape, m, np.random.default_rng(seed))
    samples = np.asarray(samples, float)
    m = len(samples)
    params = dict(
        shape=shape.name,
        energy=energy,
        basis=basis,
        m=m,
        spatial=spatial,
        k=k if spatial == "reduced" else None,
        seed=seed,
        rounds=rounds,
    )
    gt_key = _hash("gt-train", shape.mesh.V, shape.mesh.F, shape.handles, shape.moving, energy, samples, rounds)
    op_key = _hash(gt_key, basis, spatial, params["k"])
    folder = config.cache_dir() if cache else None
    times = {}
    if folder is not None and (folder / f"op-{op_key}.npz").exists():
        t0 = time.perf_counter()
        op = DefOp.load(folder / f"op-{op_key}.npz")
        times["load"] = time.perf_counter() - t0
        gt = folder / f"gt-{gt_key}.npz"
        X = conv = None
        if gt.exists():
            with np.load(gt) as z:
                X, conv = z["X"], z["converged"]
        return op, TrainingRecord(samples, X, conv, times, "operator", params)

    meta = {"shape": shape.name, "energy": energy, "seed": seed}
    gt_path = None if folder is None else folder / f"gt-{gt_key}.npz"
    if gt_path is not None and gt_path.exists():
        with np.load(gt_path) as z:
            X, conv = z["X"], z["converged"]
            if "times" in z:  # how long the cached solves took when they ran
                times.update(json.loads(str(z["times"])))
        cache_state = "ground truth"
    else:
        cache_state = "none"
        n = shape.n_moving
        nb = min(m, 2 * n + 1)
        t0 = time.perf_counter()
        Xb, cb = solve_samples(shape, samples[:nb], energy, None, n_jobs, progress, desc="bootstrap solves")
        lin = fit(shape.mesh, shape.handles, shape.moving, samples[:nb], Xb, "linear", "hat", meta=meta)
        times["bootstrap"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        X, conv = Xb, cb
        if m > nb:
            starts = _warm_starts(lin, samples[nb:], shape.mesh, energy)
            Xr, cr = solve_samples(shape, samples[nb:], energy, starts, n_jobs, progress, desc="sample solves")
            X, conv = np.concatenate([Xb, Xr]), np.concatenate([cb, cr])
        for _ in range(rounds - 1):
            # a smooth predictor (not an interpolant, which would reproduce a bad local minimum)
            smooth = "quadratic" if m + 1 >= 1 + 3 * n + 2 * n * n else "linear"
            inter = fit(shape.mesh, shape.handles, shape.moving, samples, X, smooth, "hat", meta=meta)
            # the current solutions and the smooth fit's predictions: the lower verified minimum of the two
            starts = [[x, w] for x, w in zip(X, _warm_starts(inter, samples, shape.mesh, energy))]
            X, conv = solve_samples(shape, samples, energy, starts, n_jobs, progress, desc="re-solves", rest=False)
        times["solve"] = time.perf_counter() - t0
        if gt_path is not None:
            np.savez(gt_path, X=X, converged=conv, times=np.array(json.dumps(times)))
    if not conv.all():
        warnings.warn(
            f"{int((~conv).sum())} of {m} sample solves did not converge; they are used as they are",
            NotConvergedWarning,
            stacklevel=2,
        )
    t0 = time.perf_counter()
    op = fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, spatial, k, meta=meta)
    times["fit"] = op.fit_time
    times["fold"] = time.perf_counter() - t0 - op.fit_time
    op.meta["stage_times"] = dict(times)  # kept with the cached operator (Table 1's preprocess column)
    if folder is not None:
        op.save(folder / f"op-{op_key}.npz")
    return op, TrainingRecord(samples, X, conv, times, cache_state, params)
