"""Training a DefOp by bootstrapping (§3.3): sample, solve the variational problem, fit.

Stages, each timed in the :class:`TrainingRecord` (CPU seconds, wall seconds beside):

1. **bootstrap**: the first dn + 1 samples (n moving handles in R^d) are solved from the rest pose and a
   *linear* operator is fitted to them;
2. **solve**: every other sample is solved globally (:meth:`defop.variational.solver.Solver.solve_best`): from the
   rest pose and from that linear operator's prediction (skipped when it flips a triangle under a
   barrier energy), keeping the lowest verified minimum; ``rounds > 1`` re-solves every sample from its
   current solution and the prediction of a smooth fit, keeping the lower;
3. **fit**: the final basis (problem 8).

The stages 1-2 are the start portfolio of :func:`defop.training.portfolios.portfolio`; every solve runs on the
sample engine (:mod:`defop.training.solves`), in parallel with joblib on every core by default (``DEFOP_N_JOBS``),
through whatever joblib backend is active, so ``with joblib.parallel_backend("dask"):`` runs them on a Dask
cluster. Ground truths and trained operators are cached on disk (``DEFOP_CACHE``, :mod:`defop.training.cache`),
keyed by a hash of everything that determines them (the solver's settings and the library version
included), so notebooks and figures never retrain.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from ..operator import handle_bases as hb
from ..operator.defop import DefOp
from ..operator.fit import check_distinct, fit
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning
from . import batch, solves, work
from . import cache as cache_mod
from . import ground_truths as truths
from . import multilevel as ml
from .record import TrainingRecord as TrainingRecord  # re-exported
from .sampling import SAMPLINGS, sample_shape

DEFAULT_M = 200

#: :func:`train`'s defaults in 3D (tetrahedral meshes): samples Q_k and solve rounds, chosen once for every 3D shape
#: with the default rigid patch samples. Measured on a torus read from STL (2,039 vertices) and ``bar_3d`` (1,519):
#: a sample costs about 1.3-1.7 CPU s a round; the held-out RMS error (20 exact rigid patch motions of the default
#: region size) at m = 60, 100, 150 was 2.5%, 1.8%, 1.8% (torus) and 1.8%, 1.4%, 1.0% (bar_3d) of the diagonal.
DEFAULT_M_3D = 150
DEFAULT_ROUNDS_3D = 1

#: :func:`train`'s default solve rounds in 2D
DEFAULT_ROUNDS = 2


def defaults(d):
    """(m, rounds): :func:`train`'s default sample count and solve rounds in dimension d (2 or 3)."""
    return (DEFAULT_M_3D, DEFAULT_ROUNDS_3D) if d == 3 else (DEFAULT_M, DEFAULT_ROUNDS)


def min_samples(basis, n, d=2):
    """The fewest samples Q_k (besides the rest pose) :func:`train` needs for a handle basis.

    Parameters
    ----------
    basis : str
        ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"``.
    n : int
        Number of moving handles.
    d : int
        Dimension (2 or 3).

    Returns
    -------
    int
        |Ψ| - 1 for the polynomial bases (``fit`` adds the rest pose), dn + 1 for TPS.
    """
    opt.choice("handle basis", basis, hb.KINDS)
    return d * n + 1 if basis == "tps" else hb.basis_size(basis, n, d=d) - 1


def check_train_options(shape, basis, m, spatial, k, seed, samples, n_jobs, rounds):
    """Validate :func:`train`'s options before any work (the shared checks of every training); returns
    (m, samples or None, n_jobs capped at the machine's cores); m None is the default of the shape's dimension
    (:func:`defaults`)."""
    opt.choice("handle basis", basis, hb.KINDS)
    opt.choice("spatial basis", spatial, ("hat", "reduced"))
    if spatial == "reduced":  # reduced_basis solves for k + 3 eigenpairs: k + 3 < n_vertices
        opt.integer("k", k, minimum=3, maximum=shape.mesh.n_vertices - 4)
    opt.seed(seed)
    n_jobs = opt.n_jobs(n_jobs)
    opt.integer("rounds", rounds, minimum=1)
    if samples is not None:
        samples = solves.check_samples(shape, samples)
        m, given = len(samples), "given samples"
    else:
        m = opt.integer("m", defaults(shape.mesh.dim)[0] if m is None else m, minimum=1)
        given = f"m = {m}"
    need = min_samples(basis, shape.n_moving, shape.mesh.V.shape[1])
    if m < need:
        raise ValueError(
            f"the {basis} handle basis needs at least {need} samples Q_k besides the rest pose for "
            f"{shape.n_moving} moving handles, got {given}"
        )
    if samples is not None and basis == "tps":  # before any solve, not after
        check_distinct(samples)
    return m, samples, n_jobs


def _operator_reader(shape, basis, spatial, n_samples):
    """``DefOp.load`` plus the checks that the cached operator is the one asked for: ``shape``'s mesh and
    handles, the handle basis Ψ, the spatial basis Φ and the sample count (a misplaced entry is not used)."""

    def read(path):
        op = DefOp.load(path)
        if op.mesh.V.shape != shape.mesh.V.shape or not np.array_equal(op.handles, shape.handles):
            raise cache_mod.CorruptEntry("the operator does not match the shape's mesh and handles")
        got = (op.handle_basis.kind, op.meta.get("spatial"), op.meta.get("n_samples"))
        if got != (basis, spatial, n_samples):
            raise cache_mod.CorruptEntry(
                f"the operator is (Ψ, Φ, m) = {got}, not the requested {(basis, spatial, n_samples)}"
            )
        if not np.isfinite(op.W).all():
            raise cache_mod.CorruptEntry("the operator's coefficients have NaN or infinite entries")
        return op

    return read


def solve_samples(
    shape,
    samples,
    energy="sarap",
    X0=None,
    n_jobs=None,
    progress=True,
    desc="solving",
    rest=True,
    checkpoint=None,
    incumbents=None,
    clock=None,
):
    """Solve problem (6) at every sample, in parallel: the lowest verified minimum over the starts
    (:meth:`defop.variational.solver.Solver.solve_best`).

    Parameters
    ----------
    shape, samples, energy, n_jobs, progress, desc, rest, checkpoint, incumbents, clock
        As in :func:`defop.training.solves.solve`.
    X0 : (m,n_vertices,d) numpy array or list, optional
        Its ``starts``: extra starts per sample, None, one (n_vertices,d) map, or a list of maps.

    Returns
    -------
    X : (m,n_vertices,d) numpy array
    converged : (m,) bool numpy array
        Verified local minimum (see :meth:`defop.variational.solver.Solver.verify`).
    """
    en.check_energy(energy)
    n_jobs = opt.n_jobs(n_jobs)
    r = solves.solve(
        shape,
        samples,
        energy,
        X0,
        incumbents,
        rest,
        n_jobs=n_jobs,
        progress=progress,
        desc=desc,
        checkpoint=checkpoint,
        clock=clock,
    )
    return r.X, r.converged


def sample_ground_truth(shape, samples, energy="sarap", X0=None, n_jobs=None, progress=True, cache=True, clock=None):
    """:func:`solve_samples` with an on-disk cache (:mod:`defop.training.cache`).

    The key holds the mesh, the handles, the energy, the solver's settings and the samples. The warm
    starts ``X0`` are not in the key: they only choose among local minima the solver accepts.

    Returns
    -------
    X : (m,n_vertices,d) numpy array
    converged : (m,) bool numpy array
    """
    en.check_energy(energy)
    samples = solves.check_samples(shape, samples)
    opt.n_jobs(n_jobs)
    store = cache_mod.open_cache(cache)
    mesh = shape.mesh
    key = None
    if store is not None:
        settings = solves.solver_key(shape, energy)
        key = cache_mod.key("gt", mesh.V, mesh.F, shape.handles, shape.moving, energy, settings, samples)

    checkpoint = None if store is None else batch.Checkpoints(store)

    def compute():
        X, conv = solve_samples(shape, samples, energy, X0, n_jobs, progress, checkpoint=checkpoint, clock=clock)
        return {"X": X, "converged": conv}

    expect = solves.gt_expect(len(samples), mesh.n_vertices, mesh.V.shape[1])
    gt = batch.load_or_compute(store, "gt", key, expect, compute)
    if checkpoint is not None:
        checkpoint.discard()  # the whole ground truth is cached
    return gt["X"], gt["converged"]


def held_out(shape, energy, m, seed, like=None, n_jobs=None, progress=True, cache=True, sampling="auto", samples=None):
    """Held-out test samples and their ground truth, solved like the training samples.

    Each test configuration is solved globally (:meth:`defop.variational.solver.Solver.solve_best`): from the rest
    pose and, when ``like`` is given, also from ``like(Q)``; the lowest verified minimum is kept (the rule
    of the training solves), so the test set sits on the same branches as the training set.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    energy : str
    m : int
        Number of test samples.
    seed : int
        Seeds their sampling (use one the training did not).
    like : defop.operator.DefOp, optional
        An operator whose predictions warm-start the second solve.
    sampling : str
        How the test configurations are drawn, as in :func:`train` (``"auto"``: handle patches moved rigidly).
    samples : (m,n,d) numpy array, optional
        The test configurations themselves (e.g. exact rigid patch motions,
        :func:`defop.training.sampling.rigid_patch_samples` with ``jitter=0``); ``m`` must be their number.

    Returns
    -------
    Q : (m,n,d) numpy array
    X : (m,n_vertices,d) numpy array
    converged : (m,) bool numpy array

    Raises
    ------
    ValueError
        Before any solve, naming the option: an unknown energy or sampling, ``m``, ``seed`` or ``n_jobs`` not an
        integer in range, ``like`` not callable, ``samples`` of the wrong shape or number, a ``DEFOP_CACHE`` that
        cannot be used.
    """
    en.check_energy(energy)
    m = opt.integer("m", m, minimum=1)
    opt.choice("sampling", sampling, SAMPLINGS)
    opt.seed(seed)
    opt.n_jobs(n_jobs)
    if like is not None and not callable(like):
        raise ValueError(f"like must be a trained operator (a DefOp) or None, got {type(like).__name__}")
    cache_mod.open_cache(cache)  # a bad DEFOP_CACHE fails here, before any work
    if samples is None:
        Q = sample_shape(shape, m, np.random.default_rng(seed), sampling)
    elif len(Q := solves.check_samples(shape, samples)) != m:
        raise ValueError(f"samples holds {len(Q)} configurations, m is {m}")
    X, conv = sample_ground_truth(shape, Q, energy, None, n_jobs, progress, cache)
    if like is not None:
        # the rest-pose solutions (cached) and like's predictions as the starts of one multi-start solve
        starts = [[x, w] for x, w in zip(X, batch.warm_starts(like, Q, shape.mesh, energy))]
        X, conv = solve_samples(shape, Q, energy, starts, n_jobs, progress, desc="warm test solves", rest=False)
    return Q, X, conv


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
    rounds=None,
    policy="auto",
    sampling="auto",
):
    """Train a DefOp for a shape: sample, bootstrap, solve, fit (§3.3).

    The defaults differ by dimension (:func:`defaults`): in 2D m = 200 samples and 2 solve rounds; in 3D m = 150
    and 1 round, the samples moving each handle patch rigidly (``sampling``): about 250 CPU s for a surface meshed at
    the default 2,000 tetrahedral vertices, within 2% RMS of the diagonal on held-out rigid patch motions
    (``benchmarks/bench_own_model.py``).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    energy : str
        ``"arap"``, ``"sarap"``, ``"isometric"`` (symmetric Dirichlet), ``"isometric_max"`` or ``"isometric_exp"``
        (see :data:`defop.variational.energies.ENERGIES`).
    basis : str
        Handle basis Ψ: ``"linear"``, ``"quadratic"``, ``"cubic"`` or ``"tps"``.
    m : int, optional
        Number of samples Q_k (default 200 in 2D, 150 in 3D; ignored when ``samples`` is given).
    spatial : str
        Φ: ``"hat"`` or ``"reduced"``.
    k : int
        Size of the reduced Φ.
    seed : int
        Seeds the sampling of Q_k.
    samples : (m,n,d) numpy array, optional
        Use these configurations instead of sampling.
    n_jobs : int, optional
        Parallel solves (default: every core).
    cache : bool
        Read and write the on-disk cache.
    progress : bool or callable
        One progress display over every stage's solves (the bootstrap solves, the sample solves, each re-solve
        round, named as it starts) with one ETA (:class:`defop.training.batch.Stages`; a callable makes the bar,
        as :func:`defop.training.batch.progress`).
    rounds : int, optional
        How many times the solve stage runs (default 2 in 2D, 1 in 3D). Rounds after the first solve every sample
        warm-started from a smooth (quadratic, or linear) fit of the current samples and keep whichever of that and
        the current solution (verified again, not re-solved) has the lower energy: this moves samples that landed in a
        higher local minimum (measured on the bar: 1 of 17 samples at 1.5x the energy of the branch its
        neighbours are on) back onto the branch.
    policy : str
        ``"full"``: every start on the mesh itself. ``"multilevel"``: the starts run on a coarse mesh of the same
        shape, the fine mesh gets one verified run per sample from the prolongated coarse winner, and a safeguard
        falls back to the full portfolio per sample (:mod:`defop.training.multilevel`; where no coarse mesh exists,
        e.g. a mesh too small or a limb thinner than the coarse spacing, it runs ``"full"`` with a
        :class:`~defop.training.multilevel.MultilevelWarning`). ``"auto"`` (default): ``"multilevel"`` wherever a
        coarse mesh exists (:func:`~defop.training.multilevel.has_coarse_level`, 2D and 3D), ``"full"`` elsewhere
        without a warning, the reason in ``record.multilevel["fallback"]``.
    sampling : str
        How the Q_k are drawn when ``samples`` is not given (:func:`defop.training.sampling.sample_shape`):
        ``"auto"`` (default) moves each handle patch of several handles rigidly (a 3D shape's patch, e.g.
        ``bar_3d``'s end face: :func:`defop.scene.handles.patches`, :func:`defop.training.sampling.rigid_patch_samples`)
        and otherwise draws each moving handle from its region (every 2D shape); ``"per_handle"`` always draws each
        handle from its own region (a patch's handles then move apart); ``"rigid"`` always moves patches rigidly.

    Returns
    -------
    defop : defop.operator.DefOp
        ``defop.meta["policy"]`` is the policy that ran.
    record : TrainingRecord

    Raises
    ------
    ValueError
        Before any solve, naming the option: an unknown energy, handle basis, spatial basis, policy or sampling; ``m``,
        ``seed``, ``k``, ``rounds`` or ``n_jobs`` that is not an integer in range; fewer samples than
        the handle basis needs (:func:`min_samples`, the message names the basis); ``samples`` of the
        wrong shape or not finite; a ``DEFOP_CACHE`` or ``DEFOP_N_JOBS`` that cannot be used.
    """
    en.check_energy(energy)
    opt.choice("policy", policy, ml.POLICIES)
    opt.choice("sampling", sampling, SAMPLINGS)
    rounds = defaults(shape.mesh.dim)[1] if rounds is None else rounds
    m, samples, n_jobs = check_train_options(shape, basis, m, spatial, k, seed, samples, n_jobs, rounds)
    store = cache_mod.open_cache(cache)  # a bad DEFOP_CACHE fails here, before any work
    if samples is None:
        samples = sample_shape(shape, m, np.random.default_rng(seed), sampling)
    used, lv, why = ml.choose(shape, policy)
    params = dict(
        shape=shape.name,
        energy=energy,
        basis=basis,
        m=m,
        spatial=spatial,
        k=k if spatial == "reduced" else None,
        seed=seed,
        rounds=rounds,
        policy=policy,
        policy_used=used,
        sampling=sampling,
    )
    gt_key = op_key = None
    if store is not None:
        gt_key = truths.train_key(shape, energy, samples, rounds, used, lv)
        op_key = cache_mod.key("op", gt_key, basis, spatial, params["k"])
    cached = _cached_operator(store, gt_key, op_key, shape, basis, spatial, samples, params, why)
    if cached is not None:
        return cached
    with batch.hold(store, "op", op_key):  # another process training this operator: wait for it, then load it
        cached = _cached_operator(store, gt_key, op_key, shape, basis, spatial, samples, params, why)
        if cached is not None:
            return cached
        return _train_new(
            shape,
            energy,
            basis,
            spatial,
            k,
            seed,
            samples,
            n_jobs,
            progress,
            rounds,
            lv,
            why,
            params,
            store,
            gt_key,
            op_key,
        )


def _cached_operator(store, gt_key, op_key, shape, basis, spatial, samples, params, why):
    """:func:`train`'s result from the cache (the operator, and its ground truth when cached), or None."""
    clock, m, used = solves.Stopwatch(), len(samples), params["policy_used"]
    op = None if store is None else store.load_with("op", op_key, _operator_reader(shape, basis, spatial, m))
    if op is None:
        return None
    times, wall = {"load": clock.cpu}, {"load": clock.wall}
    gt = truths.load(store, gt_key, m, shape.mesh.n_vertices, shape.mesh.dim)
    X, conv = (None, None) if gt is None else gt[:2]
    info = _levels_info(used, why, None if gt is None else gt[2].get("multilevel"))
    done = float("nan") if gt is None else work.recorded(gt[2], shape.mesh)
    units = work.units(shape.mesh)
    return op, TrainingRecord(samples, X, conv, times, "operator", params, used, info, wall, done, units)


def _train_new(
    shape, energy, basis, spatial, k, seed, samples, n_jobs, progress, rounds, lv, why, params, store, gt_key, op_key
):
    """:func:`train`'s solves (or its cached ground truth) and fit, the operator stored in the cache."""
    m, used = len(samples), params["policy_used"]
    meta = {"shape": shape.name, "energy": energy, "seed": seed, "policy": used}
    X, conv, times, wall, info, cache_state, done = truths.ground_truth(
        shape, samples, energy, n_jobs, progress, rounds, store, gt_key, lv, meta
    )
    info = _levels_info(used, why, info)
    if not conv.all():
        warnings.warn(
            f"{int((~conv).sum())} of {m} sample solves did not converge; they are used as they are",
            NotConvergedWarning,
            stacklevel=opt.user_stacklevel(),
        )
    op = _fit_timed(shape, samples, X, basis, spatial, k, meta, times, wall)
    if info.get("rule") is not None:
        op.meta["safeguard_fired"] = int(sum(1 for r in info["rule"] if r))
    if store is not None:
        store.store_with("op", op_key, op.save)
    units = work.units(shape.mesh)
    return op, TrainingRecord(samples, X, conv, times, cache_state, params, used, info, wall, done, units)


def _fit_timed(shape, samples, X, basis, spatial, k, meta, times, wall):
    """The final fit (problem 8), its CPU seconds in ``times`` (``fit`` and ``fold``, split as their wall seconds)
    and its wall seconds in ``wall``; they are kept with the operator (Table 1's preprocess column)."""
    clock = solves.Stopwatch()
    op = fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, spatial, k, meta=meta)
    cpu, total = clock.cpu, clock.wall
    share = op.fit_time / total if total > 0 else 1.0
    times["fit"], times["fold"] = cpu * share, cpu * (1.0 - share)
    wall["fit"], wall["fold"] = op.fit_time, total - op.fit_time
    op.meta["stage_times"] = dict(times)
    return op


def _levels_info(used, why, info):
    """``TrainingRecord.multilevel``: the per-sample decisions (or {}), and why one level ran where it did."""
    out = dict(info or {})
    out["fallback"] = why
    return out
