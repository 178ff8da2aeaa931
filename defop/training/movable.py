"""Training the movable-handle operator D(x; P, Q): joint samples (P_k, Q_k), their truth, the fit.

A joint draw takes each movable handle's rest vertex uniformly from its placement region (:mod:`defop.scene.placement`)
and Q from the shape's sampling regions centred at P (the Q regions travel with P): :func:`sample_joint`. The training
samples (:func:`train_movable`) are the first m draws, or (``design="spread"``) the m draws of a pool of :data:`POOL` m
that lie farthest apart in Ψ's joint coordinates (:func:`spread_joint`), so that fewer corners of the joint space are
left without a sample near them. The truth at each sample is problem (6) with the handles at those vertices, solved by
the verified solver from the rest pose (:meth:`defop.variational.solver.Solver.solve_best`), through the sample engine
(:func:`defop.training.solves.solve`: parallel, checkpointed, cached; the placement regions are part of the key).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from .. import options as opt
from ..operator.fit import farthest_points
from ..operator.movable import fit_movable, joint_points
from ..scene.placement import PlacementRegions
from ..scene.shapes import Shape
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning
from . import batch, portfolios, solves, work
from . import cache as cache_mod
from . import multilevel as ml
from .sampling import sample_shape


def sample_placements(placement, m, rng):
    """m rest placements: each movable handle's vertex uniform over its region, (m, b) int numpy array."""
    m, rng = opt.integer("m", m, minimum=1), opt.rng(rng)
    return np.stack([rng.choice(v, size=m) for v in placement.vertices], axis=1).astype(np.int64)


def sample_joint(shape, placement, m, rng, n_q=1):
    """Joint samples: ``m`` placements, ``n_q`` configurations Q around each (the regions centred at P), drawn as
    a fixed-P training draws them (:func:`defop.training.sampling.sample_shape`: in 3D each patch moved rigidly).

    Returns
    -------
    idx : (m n_q, b) int numpy array
    Q : (m n_q, n, d) numpy array
    """
    m = opt.integer("m", m, minimum=1)
    n_q = opt.integer("n_q", n_q, minimum=1)
    rng = opt.rng(rng)
    idx = sample_placements(placement, m, rng)
    Q = np.stack([sample_shape(shape_at(shape, placement, i), n_q, rng) for i in idx])
    return np.repeat(idx, n_q, axis=0), Q.reshape(m * n_q, shape.n_moving, shape.mesh.dim)


#: :func:`spread_joint`: the pool of uniform joint draws, in training samples (chosen once for every shape; on the
#: bar at m = 1,000 it took the held-out error from 35.4x to 7.5x the retrained (the mean of 3 seeds from 30.2x to
#: 13.2x), on the aleph from 2.22x to 2.14x: benchmarks/README.md, 2026-12-02, fifth part)
POOL = 4

#: the designs of :func:`train_movable`'s samples: ``"spread"`` (:func:`spread_joint`) or ``"uniform"`` (the first
#: m draws of :func:`sample_joint`)
DESIGNS = ("spread", "uniform")


def spread_joint(shape, placement, m, rng, n_q=1, pool=POOL):
    """Joint training samples spread over the joint space: ``pool`` × m placements drawn by :func:`sample_joint`
    (``n_q`` Q each), of which the m lying farthest apart in Ψ's coordinates z (:func:`defop.operator.movable.
    joint_points`, the scales of the pool; a placement's n_q samples as one point) are kept, picked greedily
    (:func:`defop.operator.fit.farthest_points`) from the draw nearest the pool's mean, in the order drawn.

    A uniform draw leaves gaps: on the bar (21 placements, an elliptic Q region) one held-out Q at the region's
    narrow end had no training sample within 40% of the ellipse at its placement and carried 73% of the mean
    error. The thin-plate spline's error grows with the distance to its data (its fill distance), which the
    greedy pick lowers at equal m where the joint space has few dimensions (the bar, R^4, m = 1,000: the pool's
    covering radius 0.17 against the uniform design's 0.50) and hardly in many (the aleph, R^20: 2.9 against 3.3).

    Returns
    -------
    idx : (m n_q, b) int numpy array
    Q : (m n_q, n, d) numpy array
    """
    m = opt.integer("m", m, minimum=1)
    n_q = opt.integer("n_q", n_q, minimum=1)
    pool = opt.integer("pool", pool, minimum=1)
    idx, Q = sample_joint(shape, placement, pool * m, opt.rng(rng), n_q)
    if pool == 1:
        return idx, Q
    z, _, _ = joint_points(shape.mesh, placement, shape.moving, idx, Q)
    z = z.reshape(pool * m, -1)  # a placement's n_q samples in a row: one point
    first = int(np.argmin(np.sum((z - z.mean(axis=0)) ** 2, axis=1)))
    pick = np.sort(farthest_points(z, m, first))
    rows = (pick[:, None] * n_q + np.arange(n_q)).ravel()
    return idx[rows], Q[rows]


def vertex_indices(name, idx, shape):
    """``idx`` as an int64 array of the given shape (None in it: any length), refusing fractional or non-finite
    entries instead of truncating them.

    Raises
    ------
    ValueError
        Naming ``name``: not numbers, the wrong shape, or an entry that is not a whole number.
    """
    a = np.asarray(idx)
    if a.dtype.kind not in "iuf" or np.iscomplexobj(a):
        raise ValueError(f"{name} must hold integer vertex indices, got an array of {a.dtype}")
    if a.ndim != len(shape) or any(want is not None and got != want for got, want in zip(a.shape, shape)):
        want = ", ".join("m" if w is None else str(w) for w in shape)
        raise ValueError(f"{name} must have shape ({want}), got {a.shape}")
    if a.dtype.kind == "f" and not (np.isfinite(a).all() and (a == np.round(a)).all()):
        bad = a[~(np.isfinite(a) & (a == np.round(a)))]
        raise ValueError(f"{name} must hold integer vertex indices, got {bad.ravel()[0]!r} (not a whole number)")
    return a.astype(np.int64)


def shape_at(shape, placement, idx):
    """The shape with its movable handles at vertices ``idx`` (b,): a fixed-P :class:`Shape` (same regions)."""
    idx = placement.resolve(vertex_indices("idx", idx, (placement.n_movable,)))
    name = f"{shape.name}@{'-'.join(map(str, idx))}"
    return Shape(
        name, shape.mesh, placement.handles_at(idx), shape.moving, shape.regions, shape.description, shape.outline
    )


def check_joint(shape, placement, idx, Q):
    """The joint samples as (idx (m, b) int64, Q (m, n, d) float), checked before any solve: Q through the checks of
    :func:`defop.training.bootstrap.train` (one configuration of every moving handle, finite), the placements
    whole vertex indices in their regions, and as many placements as configurations."""
    Q = solves.check_samples(shape, Q, "Q")
    idx = vertex_indices("idx", idx, (None, placement.n_movable))
    if len(idx) != len(Q):
        raise ValueError(f"idx and Q must give one placement per configuration: {len(idx)} placements, {len(Q)} Q")
    for i in np.unique(idx, axis=0):
        placement.resolve(i)  # every placement in its regions
    return idx, Q


def _joint_key(shape, placement, idx, Q, energy, lv=None):
    """The cache key of the joint solves: mesh, handles, placement regions, energy, solver settings, samples; under
    the multilevel policy (``lv``, the coarse level) also its constants, its portfolio and the coarse mesh with the
    vertices the handles map to (the full policy's key is what it always was)."""
    mesh = shape.mesh
    regions = placement.to_arrays().values()
    settings = solves.solver_key(shape, energy)
    policy = []
    if lv is not None:
        coarse = lv.coarse.mesh
        what = {"policy": "multilevel", "coarse portfolio": "rest", **ml.constants()}
        policy = [what, coarse.V, coarse.F, lv.fine_vertices, lv.coarse_vertices]
    return cache_mod.key(
        "gt-movable", mesh.V, mesh.F, shape.handles, shape.moving, *regions, energy, settings, idx, Q, *policy
    )


#: ``policy="auto"`` of the joint solves runs two levels in these dimensions only. Each placement builds its own
#: solvers on both levels (its handles differ; its samples share them), so the coarse level saves less than it does
#: for a fixed-P sample: measured side by side on the same samples (benchmarks/README.md), the two levels took 1.32x
#: fewer CPU s on bar_3d (936 vertices) but 1.3x more on the bar (596) and 1.15x more on the aleph (2,810).
JOINT_AUTO_DIMS = (3,)


def joint_level(shape, placement, policy="auto"):
    """The policy that runs the joint solves (:func:`defop.training.multilevel.choose`; ``"auto"``: two levels in
    :data:`JOINT_AUTO_DIMS` only), the coarse mesh holding every vertex a movable handle's patch member may sit on
    (:attr:`PlacementRegions.layout`), so that each placement's handles are coarse vertices too:
    ``(used, level or None, why)``."""
    if policy == "auto" and shape.mesh.dim not in JOINT_AUTO_DIMS:
        return "full", None, f"auto: joint samples run on one level in {shape.mesh.dim}D (JOINT_AUTO_DIMS)"
    where = np.concatenate([lay.ravel() for lay in placement.layout])
    return ml.choose(shape, policy, vertices=where)


def solve_joint(shape, placement, idx, Q, energy="sarap", n_jobs=None, progress=True, cache=True, policy="full"):
    """The verified solutions of problem (6) at joint samples (handles at ``idx`` (m, b), targets Q (m, n, d)).

    Each sample is solved by the sample engine (:func:`defop.training.solves.solve` with the handles per sample),
    cached and checkpointed: ``policy="full"`` (default) from the rest pose on the mesh itself; ``"multilevel"``
    (and ``"auto"`` where :func:`joint_level` picks it) as a fixed-P training's multilevel policy
    (:mod:`defop.training.multilevel`) with the rest pose as the coarse portfolio: the rest-pose solve on the coarse
    mesh (the placement's handles at their coarse vertices, :func:`joint_level`), one fine run from the prolongated
    minimum, the same safeguard and verification (falling back per sample to the fine rest pose and the prolongated
    start, the lowest verified minimum kept).

    Returns
    -------
    X : (m, n_vertices, d) numpy array
    converged : (m,) bool numpy array

    Raises
    ------
    ValueError
        Before any solve: Q not (m, n, d) for the n moving handles (one target each, no broadcast) or not finite;
        idx not (m, b) whole vertex indices in their regions; idx and Q of different lengths; an unknown policy.
    """
    return _solve_joint(shape, placement, idx, Q, energy, n_jobs, progress, cache, policy)[:2]


#: a part of the checkpoint keys of the joint solves: they run in :func:`by_placement`'s order
BY_PLACEMENT = "by placement"


def by_placement(idx):
    """(m,) int numpy array: the order that puts the samples of one placement ``idx`` (m, b) in a row, each
    placement where it first occurs and its samples in their order (a solve does not depend on the order)."""
    _, first, inverse = np.unique(idx, axis=0, return_index=True, return_inverse=True)
    return np.argsort(first[inverse.ravel()], kind="stable")


def in_order(arrays, order):
    """The per-sample arrays of ``arrays`` (those of ``len(order)``) back in the samples' order from ``order``'s."""
    back = np.argsort(order)
    return {k: v[back] if len(v) == len(order) and k != "cpu_seconds" else v for k, v in arrays.items()}


def _multilevel_joint(lv, Q, handles, energy, n_jobs, progress, ck, key):
    """The joint samples under the multilevel policy: (the truth's arrays, CPU seconds spent in other processes)."""
    clock = solves.Stopwatch()
    coarse = [lv.coarse_of(h) for h in handles]
    run = clock.add(
        solves.solve(
            lv.coarse,
            Q,
            energy,
            handles=coarse,
            keep="all",
            n_jobs=n_jobs,
            progress=progress,
            desc="coarse joint solves",
        )
    )
    key_of = None if ck is None else lambda a, b: cache_mod.key("ml-fine-movable", key, BY_PLACEMENT, a, b)
    X, conv, info, remote = portfolios.refine(
        lv, Q, energy, run.runs, ml.refine_one, ml.RULES, n_jobs, progress, ck, key_of, handles=handles
    )
    clock.remote += remote
    rule = np.array([ml.RULES.index(r) + 1 if r else 0 for r in info["rule"]], np.int64)
    spent = {"work": run.work + np.array(info["work"]), "setup": run.setup + np.array(info["setup"])}
    return {"X": X, "converged": conv, "cpu_seconds": np.array([clock.cpu]), "rule": rule, **spent}, clock.remote


def _solve_joint(shape, placement, idx, Q, energy, n_jobs, progress, cache, policy="full", counted=False):
    """:func:`solve_joint` plus the CPU seconds its solves spent in other processes (now) and in all (when they
    ran, also after a cache hit), the policy that ran and its record (:attr:`MovableRecord.multilevel`, with the
    per-sample ``"work"`` and ``"setup"`` of :mod:`defop.training.work`, NaN for a truth cached without them, and
    their ``"work_units"``; ``counted``: a cached truth without them is solved again, the truth is cached under its
    units and solved without a checkpoint, so every sample's work is counted here: none is loaded without it)."""
    en.check_energy(energy)
    opt.choice("policy", policy, ml.POLICIES)
    check_placement(shape, placement)
    idx, Q = check_joint(shape, placement, idx, Q)
    used, lv, why = joint_level(shape, placement, policy)
    mesh, store = shape.mesh, cache_mod.open_cache(cache)
    units = work.units(mesh)
    key = None if store is None else _joint_key(shape, placement, idx, Q, energy, lv)
    if counted and key is not None:
        key = cache_mod.key("counted", key, units)
    ck = None if store is None or counted else batch.Checkpoints(store)
    order = by_placement(idx)  # the samples of one placement in a row: one solver each (solves.Problem.solver_for)
    handles = np.array([placement.handles_at(i) for i in idx[order]])  # a movable handle's patch moves with it
    spent = []

    def compute():  # the solves' CPU seconds are kept with the truth (MovableRecord.solve_cpu_seconds)
        if lv is not None:
            arrays, remote = _multilevel_joint(lv, Q[order], handles, energy, n_jobs, progress, ck, key)
            spent.append(remote)
            return in_order(arrays, order)
        r = solves.solve(
            shape,
            Q[order],
            energy,
            n_jobs=n_jobs,
            progress=progress,
            desc="joint solves",
            checkpoint=ck,
            handles=handles,
            key_of=lambda a, b: cache_mod.key("chunk-movable", key, BY_PLACEMENT, a, b),
        )
        spent.append(r.cpu_seconds - r.local_cpu_seconds)
        arrays = {"X": r.X, "converged": r.converged, "cpu_seconds": np.array([r.cpu_seconds])}
        return in_order({**arrays, "work": r.work, "setup": r.setup}, order)

    expect = solves.gt_expect(len(Q), mesh.n_vertices, mesh.dim)
    if counted:
        expect.update({"work": ((len(Q),), "f"), "setup": ((len(Q),), "f")})
    gt = batch.load_or_compute(store, "gt", key, expect, compute)
    if ck is not None:
        ck.discard()
    solve_cpu = float(gt["cpu_seconds"][0]) if "cpu_seconds" in gt else float("nan")  # NaN: stored without it
    nan = np.full(len(Q), np.nan)  # a truth cached without its work: not known
    info = {"fallback": why, "work": gt.get("work", nan), "setup": gt.get("setup", nan), "work_units": units}
    if lv is not None:
        info["rule"] = ["" if r == 0 else ml.RULES[r - 1] for r in gt["rule"]]
        info["coarse_vertices"] = lv.coarse.mesh.n_vertices
    return gt["X"], gt["converged"], sum(spent), solve_cpu, used, info


@dataclasses.dataclass
class MovableRecord:
    """What :func:`train_movable` did: the joint samples, their truth, the wall seconds it took and its CPU seconds
    (summed over every process that solved), the CPU seconds of the joint solves when they ran (kept in the cache
    with the truth, so the same after a cache hit; NaN for a truth cached without them) and of the fit, the policy
    of the solves (``"full"`` or ``"multilevel"``) and, as ``TrainingRecord.multilevel``, why one level ran where
    two were asked for (``"fallback"``) and under the multilevel policy the safeguard's rule per sample (``"rule"``,
    "" where none fired) and the coarse mesh's vertex count (``"coarse_vertices"``)."""

    idx: np.ndarray
    Q: np.ndarray
    X: np.ndarray
    converged: np.ndarray
    seconds: float
    cpu_seconds: float = 0.0
    solve_cpu_seconds: float = float("nan")
    fit_cpu_seconds: float = 0.0
    policy: str = "full"
    multilevel: dict = dataclasses.field(default_factory=dict)
    #: the work of the joint solves of these samples, their setup included, the fit's not (:mod:`defop.training.
    #: work`; NaN: not known) and, from :func:`defop.training.movable_budget.train_within`, the budget that chose m
    #: (``"target"``, ``"factor"``, ``"fit"``: the fit's work, counted against the target beside ``work``,
    #: ``"solved"``: the samples solved to find m, ``"capped"``); ``work_units`` (:func:`defop.training.work.units`)
    work: float = float("nan")
    budget: dict = dataclasses.field(default_factory=dict)
    work_units: dict = dataclasses.field(default_factory=dict)


def check_placement(shape, placement):
    """Raise ValueError unless ``placement`` holds regions of ``shape``'s mesh and handles."""
    if not isinstance(placement, PlacementRegions):
        raise ValueError(
            f"placement must be a PlacementRegions (placement_regions(shape, ...)), got {type(placement).__name__}"
        )
    mesh = placement.mesh
    same_mesh = mesh is shape.mesh or (np.array_equal(mesh.V, shape.mesh.V) and np.array_equal(mesh.F, shape.mesh.F))
    same_handles = np.array_equal(placement.handles, shape.handles) and np.array_equal(placement.moving, shape.moving)
    if not (same_mesh and same_handles):
        raise ValueError(
            f"placement holds regions of another mesh or other handles ({mesh.n_vertices} vertices, "
            f"handles {placement.handles.tolist()}) than shape {shape.name!r} ({shape.mesh.n_vertices} "
            f"vertices, handles {np.asarray(shape.handles).tolist()}): make it by "
            "placement_regions(shape, ...)"
        )


def train_movable(
    shape,
    placement,
    energy="sarap",
    m=400,
    seed=0,
    n_q=1,
    n_jobs=None,
    cache=True,
    progress=True,
    centres="auto",
    policy="auto",
    design="uniform",
):
    """Sample (P_k, Q_k) (``design``: ``"uniform"``, default, the first m draws of :func:`sample_joint`, the sequence
    whose prefix :func:`defop.training.movable_budget.train_within` takes; ``"spread"``, the m farthest apart of
    :data:`POOL` m draws, :func:`spread_joint`, not a prefix of one sequence, so not yet the budget's), solve problem
    (6) at each (cached; :func:`solve_joint` under ``policy``, default ``"auto"``: through the coarse level wherever one
    exists in the dimensions where that saves CPU seconds, :func:`joint_level`), fit D(x; P, Q)
    (:func:`defop.operator.movable.fit_movable`; ``centres``: how many TPS centres, default one per sample,
    :func:`defop.operator.fit.centre_count`).

    Returns
    -------
    op : defop.operator.movable.MovableOp
    record : MovableRecord
    """
    en.check_energy(energy)
    m = opt.integer("m", m, minimum=2)
    n_q = opt.integer("n_q", n_q, minimum=1)
    opt.seed(seed)
    opt.choice("policy", policy, ml.POLICIES)
    opt.choice("design", design, DESIGNS)
    check_placement(shape, placement)
    clock = solves.Stopwatch()
    draw = spread_joint if design == "spread" else sample_joint
    idx, Q = draw(shape, placement, -(-m // n_q), np.random.default_rng(seed), n_q)
    X, conv, remote, solve_cpu, used, info = _solve_joint(
        shape, placement, idx, Q, energy, n_jobs, progress, cache, policy
    )
    clock.remote += remote
    spent = float(work.prefix(info.pop("work"), info.pop("setup"), work.first_of(idx))[-1])  # setup once a placement
    units = info.pop("work_units")
    op, fit_cpu = fit_joint(shape, placement, idx, Q, X, conv, energy, seed, centres)
    record = MovableRecord(idx, Q, X, conv, clock.wall, clock.cpu, solve_cpu, fit_cpu, used, info, spent)
    record.work_units = units
    return op, record


def fit_joint(shape, placement, idx, Q, X, conv, energy, seed, centres):
    """D(x; P, Q) fitted to solved joint samples (:func:`defop.operator.movable.fit_movable`), a warning naming the
    solves that did not converge (used as they are): (op, the fit's CPU seconds). ``idx`` (m, b), ``Q`` (m, n, d),
    ``X`` (m, n_vertices, d), ``conv`` (m,) bool; the rest as :func:`train_movable`'s."""
    if not conv.all():
        warnings.warn(
            f"{int((~conv).sum())} of {len(conv)} joint solves did not converge; used as they are",
            NotConvergedWarning,
            stacklevel=3,
        )
    meta = {"shape": shape.name, "energy": energy, "seed": seed}
    fitting = solves.Stopwatch()
    op = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X, meta, centres=centres)
    return op, fitting.cpu


#: the budget of a joint training, in fixed-P trainings (at m = 200, the 2D default)
BUDGET = 5


def training_solves(record):
    """How many solves of problem (6) a fixed-P training ran, from its :class:`~defop.training.record.TrainingRecord`:
    every sample once per round (``params["rounds"]``; the full policy's first round holds the bootstrap solves),
    and once more on the fine mesh after the multilevel policy's coarse rounds. A coarse solve counts as one."""
    rounds = int(record.params["rounds"])
    return len(record.samples) * (rounds + (record.policy == "multilevel"))


def budget_samples(record, factor=BUDGET):
    """The joint m within a budget of ``factor`` fixed-P trainings: ``factor`` × the samples of ``record`` (the
    fixed-P training's record, e.g. ``dop.train(shape, m=200)``).

    A joint sample runs, under :func:`train_movable`'s default policy, one solve from the rest pose on the full
    mesh in 2D, and in 3D what a fixed-P sample runs under ``dop.train``'s: its portfolio on the coarse mesh (the
    placement's handles at their coarse vertices), then one fine run from the prolongated minimum, with the same
    safeguard (:data:`JOINT_AUTO_DIMS`). Either way each placement builds its own fine solver (its samples share
    it, :func:`by_placement`), so a joint sample costs more than a fixed-P sample where placements rarely repeat
    (the aleph, 2,810 vertices: 1.38x, its bi-Laplacian's LU and the longer rest-pose solve) and about as much where
    they do (bar_3d, 19 placements: 1.07x at m = 1,000; benchmarks/README.md, 2026-12-02, fourth part). The rule is
    a count, the same m wherever the same back end runs the same solves, not a bound on CPU seconds (the lesson and
    ``bench_movable.py`` print the CPU seconds each side took; ``bench_movable_policy.py`` both policies).

    Raises
    ------
    ValueError
        ``factor`` not a positive integer.
    """
    return opt.integer("factor", factor, minimum=1) * len(record.samples)
