"""The sample engine: the one code that solves problem (6) for many samples.

Every batch of solves in the library runs here: :func:`solve` (each sample independently: its starts, the rest pose
and an incumbent, the lowest verified minimum kept, or every end point), and :mod:`defop.training.paths` (paths of
solves, each step warm-started from the last: continuation sweeps and decision-dependent paths).
:mod:`defop.training.portfolios` builds the training policies on them (the full start portfolio, on the fine or a
coarse mesh, and the multilevel fine stage).

The work is split by :func:`defop.training.batch.parallel_map` (joblib, a Dask cluster included), checkpointed by
:func:`~defop.training.batch.map_checkpointed` under a key of everything that determines it (:func:`chunk_key`) and
shown by progress bars. Timing follows one rule: every solve returns its own CPU seconds
(``time.process_time`` deltas, measured where it ran: the loky workers persist, so the parent's view of its
children's usage misses them); :class:`Solves` sums them, and reports the wall seconds beside.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
import typing
import warnings

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from ..operator import core
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning, Solver
from . import batch, work
from . import cache as cache_mod

__all__ = [
    "Item",
    "Problem",
    "Run",
    "Solves",
    "Stopwatch",
    "check_handles",
    "check_samples",
    "chunk_key",
    "gt_expect",
    "solve",
    "solve_chunk",
    "solver_key",
    "starts_parts",
    "training_cpu",
]


class Item(typing.NamedTuple):
    """One sample's result: its solution, energy and verification, the CPU seconds of its solves in process ``pid``,
    every end point ``(X, energy, converged)`` when the engine keeps them all (else None), and its work
    (:mod:`defop.training.work`: its factorisations, its solver's setup; NaN: not counted, e.g. loaded)."""

    X: np.ndarray
    energy: float
    converged: bool
    cpu: float = 0.0
    pid: int = 0
    runs: list | None = None
    work: float = float("nan")
    setup: float = float("nan")


@dataclasses.dataclass
class Solves:
    """The engine's result for m samples.

    Attributes
    ----------
    X : (m, n_vertices, d) numpy array
    energy : (m,) numpy array
        The energy of each solution (NaN where it was loaded from a checkpoint that did not hold it).
    converged : (m,) bool numpy array
        Verified local minimum (:meth:`defop.variational.solver.Solver.verify`).
    cpu_seconds : float
        CPU seconds of the solves, summed over the processes they ran in (0 for checkpoints loaded).
    wall_seconds : float
    local_cpu_seconds : float
        The part of ``cpu_seconds`` spent in this process (:class:`Stopwatch` counts it once).
    runs : list or None
        Per sample every end point ``(X, energy, converged)`` (``keep="all"``), else None.
    work, setup : (m,) numpy arrays
        Per sample the work of its factorisations and its solver's setup (:mod:`defop.training.work`; NaN where
        loaded from a checkpoint).
    """

    X: np.ndarray
    energy: np.ndarray
    converged: np.ndarray
    cpu_seconds: float = 0.0
    wall_seconds: float = 0.0
    local_cpu_seconds: float = 0.0
    runs: list | None = None
    work: np.ndarray | None = None
    setup: np.ndarray | None = None


def collect(items, wall):
    """:class:`Solves` of a list of :class:`Item` and the wall seconds they took."""
    here = os.getpid()
    cpu = float(sum(it[3] for it in items))
    local = float(sum(it[3] for it in items if it[4] == here))
    runs = [it[5] for it in items] if items and items[0][5] is not None else None
    return Solves(
        np.array([it[0] for it in items]),
        np.array([it[1] for it in items], float),
        np.array([it[2] for it in items], bool),
        cpu,
        float(wall),
        local,
        runs,
        np.array([it.work for it in items], float),
        np.array([it.setup for it in items], float),
    )


class Stopwatch:
    """CPU and wall seconds of a stage: this process's own work plus the engine's solves wherever they ran."""

    def __init__(self):
        self.t0, self.w0, self.remote = time.process_time(), time.perf_counter(), 0.0

    def add(self, solves):
        """Count a :class:`Solves` (its solves in other processes; those here are in this process's clock)."""
        self.remote += solves.cpu_seconds - solves.local_cpu_seconds
        return solves

    @property
    def cpu(self):
        return time.process_time() - self.t0 + self.remote

    @property
    def wall(self):
        return time.perf_counter() - self.w0


def training_cpu(stage_times):
    """CPU seconds that a training took: every stage of ``stage_times`` (``bootstrap``, ``solve``, ``fit``, ``fold``
    for the full policy; ``coarse``, ``fine``, ``fit``, ``fold`` for the multilevel one) but ``load`` (a cache hit)."""
    return float(sum(t for s, t in stage_times.items() if s != "load"))


def check_samples(shape, samples, name="samples"):
    """(m,n,d) float array of configurations of the shape's n moving handles, finite, m >= 1 (d from the mesh)."""
    samples = opt.real_array(name, samples)  # complex, bool, strings, objects: named, not cast
    n, d = shape.n_moving, shape.mesh.V.shape[1]
    if samples.ndim != 3 or samples.shape[1:] != (n, d) or len(samples) == 0:
        raise ValueError(f"{name} must have shape (m, {n}, {d}), m >= 1, for {n} moving handles, got {samples.shape}")
    if not np.isfinite(samples).all():
        raise ValueError(f"{name} has NaN or infinite entries")
    return samples


def check_handles(shape, handles, m):
    """(m, h) int64 handle vertices per sample (h the shape's handles), whole numbers in range; a ValueError naming
    ``handles`` otherwise (a shorter list would drop samples)."""
    a = np.asarray(handles)
    h = len(shape.handles)
    if a.shape != (m, h):
        raise ValueError(f"handles must have shape ({m}, {h}): the {h} handle vertices of each sample, got {a.shape}")
    return core.vertex_indices("handles", a.reshape(-1), shape.mesh.n_vertices).reshape(m, h)


def solver_key(shape, energy):
    """The settings of the engine's solver, for the cache keys.

    Read from a Solver built like the engine's but on one simplex of the shape's dimension: its settings depend on
    the dimension (S-ARAP's default smoothing, :data:`defop.variational.solver.SMOOTHING_3D`), not on the mesh, and
    this takes 0.1 ms instead of 45 ms on the octopus (3911 vertices).
    """
    d = shape.mesh.dim
    tiny = Mesh(np.vstack([np.zeros(d), np.eye(d)]), np.arange(d + 1)[None])
    return cache_mod.solver_settings(Solver(tiny, np.arange(d), energy))


def gt_expect(m, n_vertices, d=2):
    """The arrays of a cached ground truth of m samples (:meth:`defop.training.cache.Cache.load`'s ``expect``)."""
    return {"X": ((m, n_vertices, d), "f"), "converged": ((m,), "b")}


def as_list(X0):
    """A sample's extra starts as a list: None -> [], one map -> [map], a list of maps as it is."""
    return [] if X0 is None else list(X0) if isinstance(X0, (list, tuple)) else [X0]


def starts_parts(starts):
    """The extra starts of some samples as :func:`defop.training.cache.key` parts (None, or arrays)."""
    parts = []
    for X0 in starts:
        group = as_list(X0)
        parts.append(len(group))
        parts += [np.asarray(x, float) for x in group]
    return parts


def chunk_key(shape, energy, samples, starts, rest, incumbents):
    """``key_of(a, b)``: the checkpoint key of samples a..b of :func:`solve` (mesh, handles, energy, the solver's
    settings, the samples, their starts, ``rest`` and the incumbents)."""
    mesh, settings = shape.mesh, solver_key(shape, energy)

    def key_of(a, b):
        return cache_mod.key(
            "chunk",
            mesh.V,
            mesh.F,
            shape.handles,
            shape.moving,
            energy,
            settings,
            samples[a:b],
            *starts_parts(starts[a:b]),
            rest,
            "incumbents",
            *starts_parts(incumbents[a:b]),
        )

    return key_of


#: How many solvers with handles per sample a :class:`Problem` keeps (the most recently used, at least one), and at
#: most how many mesh vertices over all of them: a kept solver holds its Hessian's pattern and LDLᵀ and its
#: bi-Laplacian's LU, 14 MB on the aleph (2,810 vertices), 18 MB on bar_3d (936). The joint solves run grouped by
#: placement (:func:`defop.training.movable.by_placement`), so one is all they re-use.
POOL_SIZE, POOL_VERTICES = 4, 1 << 13


@dataclasses.dataclass
class Problem:
    """What every sample of a batch shares: the mesh, the default handles, the energy, the solver's settings and
    the policy (``rest``: also solve from the rest pose; ``keep``: ``"best"`` or ``"all"`` end points); the solvers
    of the handle sets met so far (``pool``, not pickled: each process keeps its own)."""

    mesh: object
    handles: np.ndarray
    energy: str
    rest: bool = True
    keep: str = "best"
    solver_kw: dict = dataclasses.field(default_factory=dict)
    solve_kw: dict = dataclasses.field(default_factory=dict)
    solver: object = None
    pool: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def __getstate__(self):
        return {**self.__dict__, "pool": {}}

    def solver_for(self, handles):
        """The solver with the handles at ``handles`` (None: the default ones, built once).

        Handles per sample (movable handles) get the solver kept for that handle set (in the order given) if there
        is one, else a new one, kept (the :data:`POOL_SIZE` most recently used, at most :data:`POOL_VERTICES` mesh
        vertices in all): the samples of one placement share its Hessian's pattern, symbolic analysis and
        bi-Laplacian factorisation as the samples of a fixed-P training share theirs. A solve leaves nothing in a
        solver that moves the next one's minimum (:meth:`defop.variational.problem.ReducedHessian.factorise` re-uses
        factors only of a matrix equal value for value)."""
        if handles is None:
            if self.solver is None:
                self.solver = Solver(self.mesh, self.handles, self.energy, **self.solver_kw)
            return self.solver
        key = np.asarray(handles, np.int64).tobytes()
        solver = self.pool.pop(key, None)
        if solver is None:
            solver = Solver(self.mesh, handles, self.energy, **self.solver_kw)
        self.pool[key] = solver  # the most recent last
        room = max(1, min(POOL_SIZE, POOL_VERTICES // self.mesh.n_vertices))
        while len(self.pool) > room:
            del self.pool[next(iter(self.pool))]
        return solver


def best_of(solver, T, starts, incumbent, rest, solve_kw):
    """(X, energy, converged): the lowest verified minimum of the local solves from ``starts`` (and the rest pose
    if ``rest``) and of ``incumbent`` as it is.

    Re-solving a verified minimum can only move it within the solver's tolerance, so the incumbent is verified
    (:meth:`Solver.verify`: one factorisation and the kink checks, against about four factorisations for a
    re-solve) and competes as it is; it wins ties. An incumbent that fails verification is re-solved like a start
    (before the others).
    """
    check = None
    if incumbent is not None:
        check = solver.verify(incumbent, solver.targets_of(T))
        if not check.ok:
            starts, check = [incumbent, *starts], None
    if check is not None and not starts and not rest:
        return incumbent, check.energy, True
    r = solver.solve_best(T, starts=starts, rest=rest, **solve_kw)
    if check is not None and (not r.converged or check.energy <= r.energy):
        return incumbent, check.energy, True
    return r.X, r.energy, r.converged


def winner(candidates):
    """The lowest verified end point (the lowest of all when none verified): ``Solver.solve_best``'s rule."""
    return min(candidates, key=lambda c: (not c[2], c[1] if np.isfinite(c[1]) else np.inf))


def all_of(solver, T, starts, incumbent, rest, solve_kw):
    """(X, energy, converged, runs): every local solve's end point kept (one solve per start that is not None, and
    one from the rest pose if ``rest``); the incumbent competes as in :func:`best_of` (it wins ties) and is not a
    new end point unless it fails verification and is re-solved."""
    cands = []
    if incumbent is not None:
        check = solver.verify(incumbent, solver.targets_of(T))
        if check.ok:
            cands.append((incumbent, float(check.energy), True))
        else:
            starts = [incumbent, *starts]
    runs = [solver.solve_best(T, starts=[X0], rest=False, **solve_kw) for X0 in starts if X0 is not None]
    if rest or not (runs or cands):
        runs.append(solver.solve_best(T, rest=True, **solve_kw))
    runs = [(r.X, float(r.energy), bool(r.converged)) for r in runs]
    X, E, ok = winner(cands + runs)
    return X, E, ok, runs


def solve_chunk(problem, jobs):
    """The engine's worker: per job ``(T, starts, incumbent, handles)`` the policy's :class:`Item`."""
    out, pid = [], os.getpid()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for T, starts, incumbent, handles in jobs:
            t0, w0 = time.process_time(), work.reading()
            solver = problem.solver_for(handles)
            if problem.keep == "all":
                X, E, ok, runs = all_of(solver, T, as_list(starts), incumbent, problem.rest, problem.solve_kw)
            else:
                (X, E, ok), runs = best_of(solver, T, as_list(starts), incumbent, problem.rest, problem.solve_kw), None
            done = work.reading() - w0, work.setup_of(solver)
            out.append(Item(X, float(E), bool(ok), time.process_time() - t0, pid, runs, *done))
    return out


def checkpointed(checkpoint, key_of, n_vertices, d):
    """``map_checkpointed``'s chunk callable: every chunk's X, energies and flags in one entry under ``key_of(a, b)``
    (None without a checkpoint)."""
    if checkpoint is None or key_of is None:
        return None

    def chunk(a, b, compute):
        fresh = []

        def arrays():
            fresh.extend(compute())
            return {"X": np.array([r[0] for r in fresh]), "converged": np.array([r[2] for r in fresh], dtype=bool)}

        got = checkpoint.load_or_compute(key_of(a, b), gt_expect(b - a, n_vertices, d), arrays)
        if fresh:  # solved now: the items keep their energies and CPU seconds (a loaded chunk cost nothing here)
            return fresh
        return [Item(X, np.nan, bool(ok)) for X, ok in zip(got["X"], got["converged"])]

    return chunk


@dataclasses.dataclass(frozen=True)
class Run:
    """How a batch runs, apart from what it solves: workers, progress, checkpoints and the clock (the keywords of
    :func:`solve` after ``solve_kw``; an unknown one is a TypeError naming it)."""

    n_jobs: int | None = None
    progress: object = True
    desc: str = "solving"
    checkpoint: object = None
    key_of: object = None
    clock: object = None


def solve(
    shape,
    samples,
    energy="sarap",
    starts=None,
    incumbents=None,
    rest=True,
    handles=None,
    keep="best",
    solver_kw=None,
    solve_kw=None,
    **run,
):
    """Solve problem (6) at every sample, independently and in parallel: the engine's batch policy.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (m, n, d) numpy array
        Configurations of the moving handles.
    energy : str
    starts : list, optional
        Extra starts per sample: None, one (n_vertices, d) map, or a list of maps.
    incumbents : list, optional
        A previous solution per sample (or None): verified, not re-solved, kept where it is the lowest verified
        minimum (:func:`best_of`).
    rest : bool
        Also solve from the rest pose (through flip-free continuation).
    handles : (m, h) int array, optional
        Per sample the handle vertices (movable handles); default ``shape.handles`` for every sample. The targets
        then are the rest positions of those vertices with the moving ones at the sample.
    keep : str
        ``"best"``: the lowest verified minimum; ``"all"``: also every end point (``Solves.runs``; no checkpoints).
    solver_kw, solve_kw : dict, optional
        Passed to ``Solver(...)`` and ``Solver.solve_best(...)`` (``tol``, ``max_iter``).
    **run
        The :class:`Run` keywords: ``n_jobs``, ``progress``, ``desc`` (as
        :func:`defop.training.batch.parallel_map`); ``checkpoint`` (a :class:`defop.training.batch.Checkpoints`:
        every :data:`~defop.training.batch.CHUNK` finished samples cached under ``key_of``, default
        :func:`chunk_key`, so an interrupted run resumes where it stopped and returns the same); ``clock`` (a
        :class:`Stopwatch` that counts the solves' CPU seconds, those in other processes too).

    Returns
    -------
    Solves
    """
    run = Run(**run)  # the caller's objects themselves (a checkpoint, a clock), never copies
    n_jobs, progress, desc, checkpoint, key_of, clock = (getattr(run, f.name) for f in dataclasses.fields(run))
    en.check_energy(energy)
    samples = check_samples(shape, samples)
    opt.choice("keep", keep, ("best", "all"))
    m = len(samples)
    starts = [None] * m if starts is None else list(starts)
    held = [None] * m if incumbents is None else list(incumbents)
    if len(starts) != m:
        raise ValueError(f"X0 must give one warm start (or None) per sample: {len(starts)} for {m} samples")
    if len(held) != m:
        raise ValueError(f"incumbents must give one map (or None) per sample: {len(held)} for {m} samples")
    problem = Problem(shape.mesh, shape.handles, energy, rest, keep, dict(solver_kw or {}), dict(solve_kw or {}))
    if handles is None:
        problem.solver_for(None)  # built once here, shipped to the workers
        targets, per = [shape.targets(q) for q in samples], [None] * m
    else:
        handles = check_handles(shape, handles, m)
        targets, per = [targets_at(shape, h, q) for h, q in zip(handles, samples)], list(handles)
    if checkpoint is not None and key_of is None and keep == "best":
        if handles is not None:  # the default key holds shape.handles, not the handles per sample
            raise ValueError("a checkpointed solve with handles per sample needs key_of (its checkpoint keys)")
        key_of = chunk_key(shape, energy, samples, starts, rest, held)
    n_vertices, d = shape.mesh.V.shape
    chunk = checkpointed(checkpoint if keep == "best" else None, key_of, n_vertices, d)
    w0 = time.perf_counter()
    items = batch.map_checkpointed(
        functools.partial(solve_chunk, problem), list(zip(targets, starts, held, per)), n_jobs, progress, desc, chunk
    )
    out = collect(items, time.perf_counter() - w0)
    at = [shape.handles] * m if handles is None else handles
    work.count(out.work, out.setup, [work.solver_key(shape.mesh, h) for h in at])
    return out if clock is None else clock.add(out)


def targets_at(shape, handles, q):
    """The targets of handles at vertices ``handles``: their rest positions, the moving ones at ``q``."""
    T = shape.mesh.V[handles].copy()
    T[shape.moving] = q
    return T


def settings_of(shape, energy, solver_kw=None):
    """The settings of the solver built on ``shape`` with ``solver_kw`` (:func:`defop.training.cache.solver_settings`),
    for the cache keys of callers that pass solver options."""
    return cache_mod.solver_settings(Solver(shape.mesh, shape.handles, energy, **dict(solver_kw or {})))
