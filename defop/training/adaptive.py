"""Adaptive sampling: choose the next samples Q_k where the current operator is least certain.

Training by :func:`defop.training.bootstrap.train` solves problem (6) at m configurations drawn uniformly from the
shape's sampling regions. :func:`train_adaptive` chooses each next batch of samples where the operator is least
certain. Measured (``benchmarks/bench_adaptive.py``, ``benchmarks/README.md``), it does NOT reach the held-out error
of 500 uniform samples with 167, on the aleph or on the octopus: 167 adaptive samples have 1.75x and 1.69x that
error, and uniform sampling reaches their error with 100 and 141 samples.

1. **initial**: ``n_initial`` uniform samples, solved exactly like :func:`~defop.training.bootstrap.train` does
   (linear bootstrap from the rest pose, then warm starts from its prediction; one round);
2. **batches**: from a fixed candidate pool (``pool`` configurations drawn once, with the seed, from the same
   regions), score every candidate by how uncertain the current operator is there: how much two fits of problem
   (8) to disjoint halves of the samples disagree in the M-norm of (8a) (:func:`uncertainty`, the default), or the
   energy residual of its prediction (:func:`energy_residual`). The ``batch`` candidates with the
   highest scores, spread apart (:func:`select_batch`), are solved (warm-started from the current operator's
   prediction, the lowest verified minimum kept: :func:`~defop.training.bootstrap.sample_ground_truth`) and
   appended;
3. **fit**: the final operator on all m samples (problem 8).

Every step is a pure function of the seed and of the ground truths, which
:func:`~defop.training.batch.parallel_map` computes per sample independently of the worker count: the same seed
gives the same samples and the same operator for any ``n_jobs`` (``tests/test_adaptive.py``). Every batch is cached
on its own (``DEFOP_CACHE``), so an interrupted adaptive training resumes at the batch it stopped in.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from ..operator.defop import ExtrapolationWarning
from ..operator.fit import fit
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning
from . import bootstrap, solves
from .batch import warm_starts
from .sampling import sample_shape

__all__ = ["disagreement", "energy_residual", "select_batch", "train_adaptive", "uncertainty"]

#: candidates evaluated at once in :func:`disagreement` (bounds the memory: chunk × n_vertices × d floats, twice)
POOL_CHUNK = 256


def disagreement(op_a, op_b, candidates, mass):
    """Squared M-norm of the difference of two operators' predictions, per candidate: the (8a) term of one pose.

    Parameters
    ----------
    op_a, op_b : callable
        ``op(Q)`` of (k,n,d) configurations -> (k,n_vertices,d) deformations (two :class:`DefOp`).
    candidates : (p,n,d) numpy array
        Configurations Q of the moving handles.
    mass : (n_vertices,) numpy array
        The lumped mass matrix' diagonal (the M of (8a)).

    Returns
    -------
    scores : (p,) numpy array
        ‖op_a(·, Q) − op_b(·, Q)‖²_M per candidate.
    """
    out = np.empty(len(candidates))
    with warnings.catch_warnings():  # a candidate may lie outside the samples' hull: the fits extrapolate
        warnings.simplefilter("ignore", ExtrapolationWarning)
        for a in range(0, len(candidates), POOL_CHUNK):
            Q = candidates[a : a + POOL_CHUNK]
            out[a : a + len(Q)] = np.einsum("v,kvc->k", mass, (op_a(Q) - op_b(Q)) ** 2)
    return out


def energy_residual(shape, op, candidates, energy="sarap"):
    """How far the operator's prediction is from a minimum of (6): ‖∇E(D(·, Q))‖² on the free vertices, in the
    M⁻¹-norm (the gradient per unit mass), per candidate.

    Zero exactly where the prediction is a critical point of the energy with the handles at Q (Prop. 1 makes it
    small at the training samples). A prediction where the energy or its gradient is not finite (an element flipped
    under a barrier energy, a degenerate one) scores +inf.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    op : callable
        ``op(Q)`` of (k,n,d) configurations -> (k,n_vertices,d) deformations (a :class:`DefOp`).
    candidates : (p,n,d) numpy array
    energy : str

    Returns
    -------
    scores : (p,) numpy array
    """
    mesh = shape.mesh
    d = mesh.V.shape[1]
    G, vol = mesh.jacobian_operator, mesh.volumes
    free = np.ones(mesh.n_vertices, bool)
    free[shape.handles] = False
    inv_mass = 1.0 / mesh.mass_matrix.diagonal()[free]
    out = np.empty(len(candidates))
    with warnings.catch_warnings():  # a candidate may lie outside the samples' hull: the fit extrapolates
        warnings.simplefilter("ignore", ExtrapolationWarning)
        for a in range(0, len(candidates), POOL_CHUNK):
            for i, X in enumerate(op(candidates[a : a + POOL_CHUNK]), start=a):
                psi, dpsi = en.gradient((G @ X.ravel()).reshape(-1, d, d), energy)
                if not (np.isfinite(psi).all() and np.isfinite(dpsi).all()):
                    out[i] = np.inf
                    continue
                g = (G.T @ (vol[:, None, None] * dpsi).ravel()).reshape(-1, d)[free]
                out[i] = float(inv_mass @ (g * g).sum(1))
    return out


def _pairwise(A, B):
    """(len(A), len(B)) Euclidean distances between flattened configurations."""
    A, B = A.reshape(len(A), -1), B.reshape(len(B), -1)
    d2 = (A * A).sum(1)[:, None] + (B * B).sum(1)[None, :] - 2 * A @ B.T
    return np.sqrt(np.maximum(d2, 0.0))


def _check_selection(scores, candidates, samples, size):
    """select_batch's arguments, or a ValueError naming the one that is wrong; returns the scores as floats."""
    candidates, samples = np.asarray(candidates), np.asarray(samples)
    if candidates.ndim != 3 or samples.ndim != 3 or len(samples) == 0 or samples.shape[1:] != candidates.shape[1:]:
        raise ValueError(
            f"candidates and samples must be (p, n, d) and (m >= 1, n, d) arrays of handle configurations, "
            f"got {candidates.shape} and {samples.shape}"
        )
    scores = np.asarray(scores, dtype=float)
    if scores.shape != (len(candidates),) or np.isnan(scores).any() or (scores < 0).any():
        raise ValueError(f"scores must be {len(candidates)} non-negative numbers (no NaN), got shape {scores.shape}")
    if not 1 <= int(size) <= len(candidates):
        raise ValueError(f"size must be between 1 and the {len(candidates)} candidates, got {size}")
    return scores


def select_batch(scores, candidates, samples, size):
    """The ``size`` candidates of highest score, spread apart, chosen greedily in a fixed order.

    A candidate's score is damped by ``1 − exp(−(r/h)²)``, r its distance to the nearest sample already taken
    (the current ``samples`` and this batch's earlier picks), h the median distance of a candidate to its nearest
    current sample: a batch does not pile up in one uncertain spot, and a candidate already sampled scores 0.
    Ties go to the lower index (``argmax``), so the choice depends only on the inputs.

    Parameters
    ----------
    scores : (p,) numpy array
        Non-negative uncertainty per candidate (:func:`disagreement`).
    candidates : (p,n,d) numpy array
    samples : (m,n,d) numpy array
        The samples Q_k taken so far.
    size : int
        How many to choose, at most p.

    Returns
    -------
    chosen : (size,) int numpy array
        Indices into ``candidates``, in the order chosen.
    """
    scores = _check_selection(scores, candidates, samples, size)
    nearest = _pairwise(candidates, samples).min(axis=1)
    h = max(float(np.median(nearest)), 1e-300)
    scores = np.nan_to_num(scores, posinf=np.finfo(float).max)  # +inf: a flipped prediction
    if not (scores > 0).any():  # no candidate is uncertain: spread the batch out (farthest from the samples)
        scores = np.ones_like(scores)
    eff = scores * -np.expm1(-((nearest / h) ** 2))
    chosen = []
    for _ in range(size):
        i = int(np.argmax(eff))
        chosen.append(i)
        eff = eff * -np.expm1(-((_pairwise(candidates, candidates[i : i + 1])[:, 0] / h) ** 2))
        eff[i] = -1.0  # taken
    return np.array(chosen, dtype=np.int64)


def uncertainty(shape, samples, X, candidates, basis="tps", spatial="hat", k=100):
    """How uncertain the operator fitted to ``samples`` is at each candidate: :func:`disagreement` of the fits to the
    even-numbered and to the odd-numbered samples (two bootstrap fits of problem (8) on disjoint halves).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (m,n,d) numpy array
    X : (m,n_vertices,d) numpy array
        Their ground truths.
    candidates : (p,n,d) numpy array

    Returns
    -------
    scores : (p,) numpy array
    """
    halves = [fit(shape.mesh, shape.handles, shape.moving, samples[i::2], X[i::2], basis, spatial, k) for i in (0, 1)]
    return disagreement(halves[0], halves[1], candidates, shape.mesh.mass_matrix.diagonal())


def _check_schedule(shape, m, n_initial, batch, pool, basis):
    """Validate :func:`train_adaptive`'s sample counts; returns (m, n_initial, batch, pool)."""
    d = shape.mesh.V.shape[1]
    need = 2 * bootstrap.min_samples(basis, shape.n_moving, d)  # each half determines the basis
    m = opt.integer("m", m, minimum=need)
    n_initial = opt.integer("n_initial", need if n_initial is None else n_initial, minimum=need, maximum=m)
    batch = opt.integer("batch", batch, minimum=1)
    pool = opt.integer("pool", 3 * (m - n_initial) if pool is None else pool, minimum=max(1, m - n_initial))
    return m, n_initial, batch, pool


def train_adaptive(
    shape,
    energy="sarap",
    basis="tps",
    m=100,
    seed=0,
    n_initial=None,
    batch=16,
    pool=None,
    criterion="disagreement",
    spatial="hat",
    k=100,
    n_jobs=None,
    cache=True,
    progress=True,
):
    """Train a DefOp on m adaptively chosen samples Q_k (see the module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    energy, basis, spatial, k, n_jobs, cache, progress
        As in :func:`defop.training.bootstrap.train`.
    m : int
        Samples in total (at least ``n_initial``).
    seed : int
        Seeds the initial samples and the candidate pool.
    n_initial : int, optional
        Uniform samples to start from (default and minimum twice :func:`~defop.training.bootstrap.min_samples`,
        2(dn + 1) for TPS: each half determines the basis).
    batch : int
        Samples added per round of scoring.
    pool : int, optional
        Size of the candidate pool (at least m − n_initial; default 3(m − n_initial)). A larger pool lets the
        criteria pick rarer, more extreme configurations, which raised the held-out error on the aleph
        (``benchmarks/README.md``).
    criterion : str
        ``"disagreement"``: the :func:`uncertainty` of two fits to disjoint halves; ``"residual"``: the current
        operator's :func:`energy_residual`. On the aleph the residual ranks candidates by their true error better
        (Spearman 0.67 against 0.36) but the samples it picks gave a higher held-out error.

    Returns
    -------
    defop : defop.operator.DefOp
    record : defop.training.bootstrap.TrainingRecord
        ``samples`` in the order they were taken; ``params["counts"]`` the sample count after the initial set and
        after each batch (fitting the first ``c`` samples gives the operator of that stage).

    Raises
    ------
    ValueError
        Before any solve, naming the option (as :func:`~defop.training.bootstrap.train`, and ``n_initial``,
        ``batch``, ``pool`` out of range).
    """
    en.check_energy(energy)
    opt.choice("criterion", criterion, ("residual", "disagreement"))
    m, n_initial, batch, pool = _check_schedule(shape, m, n_initial, batch, pool, basis)
    bootstrap.check_train_options(shape, basis, m, spatial, k, seed, None, n_jobs, 1)
    Q = sample_shape(shape, n_initial, np.random.default_rng(seed))
    candidates = sample_shape(shape, pool, np.random.default_rng([seed, 1]))
    _, rec = bootstrap.train(
        shape, energy, "linear", samples=Q, rounds=1, n_jobs=n_jobs, cache=cache, progress=progress
    )  # the initial solves exactly as train's, cached
    X, conv = rec.X, rec.converged
    initial = solves.training_cpu(rec.stage_times)
    clock = solves.Stopwatch()  # the batches (the initial training's CPU seconds are its record's)
    taken = np.zeros(pool, bool)
    counts = [n_initial]
    while len(Q) < m:
        current = fit(shape.mesh, shape.handles, shape.moving, Q, X, basis, spatial, k)
        if criterion == "residual":
            scores = energy_residual(shape, current, candidates, energy)
        else:
            scores = uncertainty(shape, Q, X, candidates, basis, spatial, k)
        scores[taken] = 0.0
        new = select_batch(scores, candidates, Q, min(batch, m - len(Q)))
        taken[new] = True
        starts = warm_starts(current, candidates[new], shape.mesh, energy)
        Xn, cn = bootstrap.sample_ground_truth(
            shape, candidates[new], energy, starts, n_jobs, progress, cache, clock=clock
        )
        Q, X, conv = np.concatenate([Q, candidates[new]]), np.concatenate([X, Xn]), np.concatenate([conv, cn])
        counts.append(len(Q))
    times = {"solve": initial + clock.cpu}
    if not conv.all():
        warnings.warn(
            f"{int((~conv).sum())} of {m} sample solves did not converge; they are used as they are",
            NotConvergedWarning,
            stacklevel=opt.user_stacklevel(),
        )
    meta = {"shape": shape.name, "energy": energy, "seed": seed, "sampling": "adaptive"}
    op = fit(shape.mesh, shape.handles, shape.moving, Q, X, basis, spatial, k, meta=meta)
    times["fit"] = op.fit_time
    params = {"shape": shape.name, "energy": energy, "basis": basis, "m": m, "spatial": spatial, "seed": seed}
    params.update(sampling="adaptive", criterion=criterion, n_initial=n_initial, batch=batch, pool=pool, counts=counts)
    return op, bootstrap.TrainingRecord(Q, X, conv, times, "none", params)
