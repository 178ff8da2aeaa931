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

import dataclasses
import warnings

import numpy as np

from .. import options as opt
from ..operator import handle_bases as hb
from ..operator.defop import DefOp
from ..operator.fit import check_distinct, fit
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning
from . import batch, portfolios, solves
from . import cache as cache_mod
from . import multilevel as ml
from .sampling import sample_shape

DEFAULT_M = 200


@dataclasses.dataclass
class TrainingRecord:
    """What training did.

    Attributes
    ----------
    samples : (m,n,d) numpy array
        The training configurations Q_k (rest pose excluded).
    X : (m,n_vertices,d) numpy array or None
        Their ground-truth deformations.
    converged : (m,) bool numpy array or None
    stage_times : dict of str -> float
        CPU seconds per stage (``bootstrap``, ``solve``, ``fit``, ``fold``; ``coarse``, ``fine`` for the multilevel
        policy; ``load``), summed over every process that worked on it (:class:`defop.training.solves.Stopwatch`).
    cache : str
        ``"operator"`` (loaded trained operator), ``"ground truth"`` (loaded samples, refitted) or ``"none"``.
    params : dict
    policy : str
        The policy that ran: ``"full"`` or ``"multilevel"`` (``params["policy"]`` is the one asked for).
    multilevel : dict
        ``"fallback"``: why one level ran where two were asked for ("" otherwise). After a multilevel training
        also, per sample: ``"rule"`` (the safeguard rule that fired, "" for none:
        :data:`defop.training.multilevel.RULES`), ``"iterations"`` (of the single fine run), ``"minima"`` (distinct
        verified coarse minima), ``"coarse_energy"`` (the coarse winner's); and ``"coarse_vertices"``.
    wall_times : dict of str -> float
        Wall seconds per stage, beside ``stage_times``.
    """

    samples: np.ndarray
    X: np.ndarray | None
    converged: np.ndarray | None
    stage_times: dict
    cache: str
    params: dict
    policy: str = "full"
    multilevel: dict = dataclasses.field(default_factory=dict)
    wall_times: dict = dataclasses.field(default_factory=dict)

    @property
    def safeguard(self) -> dict:
        """How often each safeguard rule fired (rule -> count; empty unless the multilevel policy ran)."""
        rules = self.multilevel.get("rule") or []
        return {r: rules.count(r) for r in ml.RULES if r in rules}

    @property
    def total_time(self) -> float:
        return float(sum(self.stage_times.values()))


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
    (m, samples or None, n_jobs capped at the machine's cores)."""
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
        m = opt.integer("m", DEFAULT_M if m is None else m, minimum=1)
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


def _load_gt(store, key, m, n_vertices, d=2):
    """(X, converged, meta) of a cached ground truth, or None."""
    entry = None if store is None else store.load("gt", key, solves.gt_expect(m, n_vertices, d))
    return None if entry is None else (entry[0]["X"], entry[0]["converged"], entry[1])


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


def held_out(shape, energy, m, seed, like=None, n_jobs=None, progress=True, cache=True):
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

    Returns
    -------
    Q : (m,n,d) numpy array
    X : (m,n_vertices,d) numpy array
    converged : (m,) bool numpy array

    Raises
    ------
    ValueError
        Before any solve, naming the option: an unknown energy, ``m``, ``seed`` or ``n_jobs`` not an
        integer in range, ``like`` not callable, a ``DEFOP_CACHE`` that cannot be used.
    """
    en.check_energy(energy)
    m = opt.integer("m", m, minimum=1)
    opt.seed(seed)
    opt.n_jobs(n_jobs)
    if like is not None and not callable(like):
        raise ValueError(f"like must be a trained operator (a DefOp) or None, got {type(like).__name__}")
    cache_mod.open_cache(cache)  # a bad DEFOP_CACHE fails here, before any work
    Q = sample_shape(shape, m, np.random.default_rng(seed))
    X, conv = sample_ground_truth(shape, Q, energy, None, n_jobs, progress, cache)
    if like is not None:
        # the rest-pose solutions (cached) and like's predictions as the starts of one multi-start solve
        starts = [[x, w] for x, w in zip(X, batch.warm_starts(like, Q, shape.mesh, energy))]
        X, conv = solve_samples(shape, Q, energy, starts, n_jobs, progress, desc="warm test solves", rest=False)
    return Q, X, conv


def _multilevel_ground_truth(lv, samples, energy, n_jobs, progress, rounds, ck, key_parts):
    """The multilevel policy (:mod:`defop.training.multilevel`): (X, converged, CPU times, wall times, info).

    The coarse stage is the full policy's start portfolio on the coarse mesh, every end point kept
    (:func:`defop.training.portfolios.portfolio`)."""
    clock = solves.Stopwatch()
    _, _, _, _, cands = portfolios.portfolio(lv.coarse, samples, energy, n_jobs, progress, rounds, keep="all")
    times, wall = {"coarse": clock.cpu}, {"coarse": clock.wall}
    clock = solves.Stopwatch()
    key_of = None if ck is None else lambda a, b: cache_mod.key("ml-fine", *key_parts, a, b)
    X, conv, info, remote = portfolios.refine(
        lv, samples, energy, cands, ml.refine_one, ml.RULES, n_jobs, progress, ck, key_of
    )
    clock.remote += remote
    times["fine"], wall["fine"] = clock.cpu, clock.wall
    info["coarse_vertices"] = lv.coarse.mesh.n_vertices
    return X, conv, times, wall, info


def _gt_key(shape, energy, samples, rounds, used, lv):
    """The ground truth's cache key: mesh, handles, energy, the solver's settings, the samples, ``rounds`` and the
    policy that runs (with the multilevel constants and the coarse mesh)."""
    mesh, settings = shape.mesh, solves.solver_key(shape, energy)
    policy = {"policy": used, "round 2": "verified incumbent"}
    coarse = []
    if lv is not None:
        policy.update(ml.constants())
        policy["coarse portfolio"] = "full"  # the coarse stage runs the full policy's portfolio (an incumbent verified)
        coarse = [lv.coarse.mesh.V, lv.coarse.mesh.F, lv.coarse.handles]
    return cache_mod.key(
        "gt-train", mesh.V, mesh.F, shape.handles, shape.moving, energy, settings, samples, rounds, policy, *coarse
    )


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
    policy="auto",
):
    """Train a DefOp for a shape: sample, bootstrap, solve, fit (§3.3).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    energy : str
        ``"arap"``, ``"sarap"``, ``"isometric"`` (symmetric Dirichlet), ``"isometric_max"`` or ``"isometric_exp"``
        (see :data:`defop.variational.energies.ENERGIES`).
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
    samples : (m,n,d) numpy array, optional
        Use these configurations instead of sampling.
    n_jobs : int, optional
        Parallel solves (default: every core).
    cache : bool
        Read and write the on-disk cache.
    progress : bool
        tqdm progress bars.
    rounds : int
        How many times the solve stage runs. Rounds after the first solve every sample warm-started from a
        smooth (quadratic, or linear) fit of the current samples and keep whichever of that and the current
        solution (verified again, not re-solved) has the lower energy: this moves samples that landed in a
        higher local minimum (measured on the bar: 1 of 17 samples at 1.5x the energy of the branch its
        neighbours are on) back onto the branch.
    policy : str
        ``"full"``: every start on the mesh itself. ``"multilevel"``: the starts run on a coarse mesh of the same
        shape, the fine mesh gets one verified run per sample from the prolongated coarse winner, and a safeguard
        falls back to the full portfolio per sample (:mod:`defop.training.multilevel`; where no coarse mesh exists,
        e.g. a mesh too small or a limb thinner than the coarse spacing, it runs ``"full"`` with a
        :class:`~defop.training.multilevel.MultilevelWarning`). ``"auto"``
        (default): ``"multilevel"`` from :data:`~defop.training.multilevel.AUTO_VERTICES` vertices on.

    Returns
    -------
    defop : defop.operator.DefOp
        ``defop.meta["policy"]`` is the policy that ran.
    record : TrainingRecord

    Raises
    ------
    ValueError
        Before any solve, naming the option: an unknown energy, handle basis, spatial basis or policy; ``m``,
        ``seed``, ``k``, ``rounds`` or ``n_jobs`` that is not an integer in range; fewer samples than
        the handle basis needs (:func:`min_samples`, the message names the basis); ``samples`` of the
        wrong shape or not finite; a ``DEFOP_CACHE`` or ``DEFOP_N_JOBS`` that cannot be used.
    """
    en.check_energy(energy)
    opt.choice("policy", policy, ml.POLICIES)
    m, samples, n_jobs = check_train_options(shape, basis, m, spatial, k, seed, samples, n_jobs, rounds)
    store = cache_mod.open_cache(cache)  # a bad DEFOP_CACHE fails here, before any work
    if samples is None:
        samples = sample_shape(shape, m, np.random.default_rng(seed))
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
    )
    gt_key = op_key = None
    if store is not None:
        gt_key = _gt_key(shape, energy, samples, rounds, used, lv)
        op_key = cache_mod.key("op", gt_key, basis, spatial, params["k"])
    clock = solves.Stopwatch()
    op = None if store is None else store.load_with("op", op_key, _operator_reader(shape, basis, spatial, m))
    if op is not None:
        times, wall = {"load": clock.cpu}, {"load": clock.wall}
        gt = _load_gt(store, gt_key, m, shape.mesh.n_vertices, shape.mesh.dim)
        X, conv = (None, None) if gt is None else gt[:2]
        info = _levels_info(used, why, None if gt is None else gt[2].get("multilevel"))
        return op, TrainingRecord(samples, X, conv, times, "operator", params, used, info, wall)
    meta = {"shape": shape.name, "energy": energy, "seed": seed, "policy": used}
    X, conv, times, wall, info, cache_state = _ground_truth(
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
    return op, TrainingRecord(samples, X, conv, times, cache_state, params, used, info, wall)


def _ground_truth(shape, samples, energy, n_jobs, progress, rounds, store, gt_key, lv, meta):
    """The training's ground truth, loaded or solved by the policy and cached: (X, converged, CPU times, wall times,
    multilevel info, cache state)."""
    gt = _load_gt(store, gt_key, len(samples), shape.mesh.n_vertices, shape.mesh.dim)
    if gt is not None:  # how long the cached solves took when they ran
        return (
            gt[0],
            gt[1],
            dict(gt[2].get("times", {})),
            dict(gt[2].get("wall", {})),
            gt[2].get("multilevel"),
            ("ground truth"),
        )
    ck = None if store is None else batch.Checkpoints(store)  # resume an interrupted run where it stopped
    info = None
    if lv is None:
        X, conv, times, wall, _ = portfolios.portfolio(shape, samples, energy, n_jobs, progress, rounds, ck, meta=meta)
    else:
        key = [gt_key]
        X, conv, times, wall, info = _multilevel_ground_truth(lv, samples, energy, n_jobs, progress, rounds, ck, key)
    if store is not None:
        meta = {"times": times, "wall": wall, "multilevel": info}
        store.store("gt", gt_key, {"X": X, "converged": conv}, meta=meta)
        ck.discard()  # the whole ground truth is cached
    return X, conv, times, wall, info, "none"


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
