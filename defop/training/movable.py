"""Training the movable-handle operator D(x; P, Q) (issue 38): joint samples (P_k, Q_k), their truth, the fit.

P_k draws each movable handle's rest vertex uniformly from its placement region
(:mod:`defop.scene.placement`); Q_k is drawn from the shape's sampling regions centred at P_k (the Q regions travel
with P). The truth at each sample is problem (6) with the handles at those vertices, solved by the verified
solver from the rest pose (:meth:`defop.variational.solver.Solver.solve_best`), through the one batch layer
(:mod:`defop.training.batch`: parallel, checkpointed, cached; the placement regions are part of the key).
"""

from __future__ import annotations

import dataclasses
import functools
import time
import warnings

import numpy as np

from .. import options as opt
from ..operator.movable import fit_movable
from ..scene.placement import PlacementRegions
from ..scene.shapes import Shape
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning, Solver
from . import batch
from . import cache as cache_mod
from .bootstrap import _gt_expect, _solver_key
from .sampling import sample_handles


def sample_placements(placement, m, rng):
    """m rest placements: each movable handle's vertex uniform over its region, (m, b) int numpy array."""
    rng = np.random.default_rng(rng)
    return np.stack([rng.choice(v, size=int(m)) for v in placement.vertices], axis=1).astype(np.int64)


def sample_joint(shape, placement, m, rng, n_q=1):
    """Joint samples: ``m`` placements, ``n_q`` configurations Q around each (the regions centred at P).

    Returns
    -------
    idx : (m n_q, b) int numpy array
    Q : (m n_q, n, d) numpy array
    """
    m = opt.integer("m", m, minimum=1)
    rng = np.random.default_rng(rng)
    idx = sample_placements(placement, m, rng)
    Q = np.stack(
        [sample_handles(shape.mesh.V[placement.handles_at(i)[shape.moving]], shape.regions, n_q, rng) for i in idx]
    )
    return np.repeat(idx, n_q, axis=0), Q.reshape(m * n_q, shape.n_moving, shape.mesh.dim)


def shape_at(shape, placement, idx):
    """The shape with its movable handles at vertices ``idx`` (b,): a fixed-P :class:`Shape` (same regions)."""
    idx = placement.resolve(np.asarray(idx, np.int64))
    name = f"{shape.name}@{'-'.join(map(str, idx))}"
    return Shape(
        name, shape.mesh, placement.handles_at(idx), shape.moving, shape.regions, shape.description, shape.outline
    )


def _solve_chunk(mesh, handles0, moving, movable, energy, jobs):
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for idx, q in jobs:
            h = handles0.copy()
            h[movable] = idx
            T = mesh.V[h].copy()
            T[moving] = q
            r = Solver(mesh, h, energy).solve_best(T, rest=True)
            out.append((r.X, r.converged))
    return out


def solve_joint(shape, placement, idx, Q, energy="sarap", n_jobs=None, progress=True, cache=True):
    """The verified solutions of problem (6) at joint samples (handles at ``idx`` (m, b), targets Q (m, n, d)).

    Returns
    -------
    X : (m, n_vertices, d) numpy array
    converged : (m,) bool numpy array
    """
    en.check_energy(energy)
    idx, Q = np.asarray(idx, np.int64), np.asarray(Q, float)
    for i in np.unique(idx, axis=0):
        placement.resolve(i)  # every placement in its regions, before any solve
    mesh = shape.mesh
    store = cache_mod.open_cache(cache)
    pa = placement.to_arrays()
    key = (
        None
        if store is None
        else cache_mod.key(
            "gt-movable",
            mesh.V,
            mesh.F,
            shape.handles,
            shape.moving,
            *pa.values(),
            energy,
            _solver_key(shape, energy),
            idx,
            Q,
        )
    )
    ck = None if store is None else batch.Checkpoints(store)

    def chunk(a, b, compute):
        ckey = cache_mod.key("chunk-movable", key, a, b)

        def arrays():
            res = compute()
            return {"X": np.array([r[0] for r in res]), "converged": np.array([r[1] for r in res], dtype=bool)}

        got = ck.load_or_compute(ckey, _gt_expect(b - a, mesh.n_vertices, mesh.dim), arrays)
        return list(zip(got["X"], got["converged"]))

    def compute():
        fn = functools.partial(_solve_chunk, mesh, shape.handles, shape.moving, placement.movable, energy)
        res = batch.map_checkpointed(
            fn, list(zip(idx, Q)), n_jobs, progress, "joint solves", None if ck is None else chunk
        )
        return {"X": np.array([r[0] for r in res]), "converged": np.array([r[1] for r in res], dtype=bool)}

    gt = batch.load_or_compute(store, "gt", key, _gt_expect(len(Q), mesh.n_vertices, mesh.dim), compute)
    if ck is not None:
        ck.discard()
    return gt["X"], gt["converged"]


@dataclasses.dataclass
class MovableRecord:
    """What :func:`train_movable` did: the joint samples, their truth and the seconds it took (wall)."""

    idx: np.ndarray
    Q: np.ndarray
    X: np.ndarray
    converged: np.ndarray
    seconds: float


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


def train_movable(shape, placement, energy="sarap", m=400, seed=0, n_q=1, n_jobs=None, cache=True, progress=True):
    """Sample (P_k, Q_k), solve problem (6) at each (cached), fit D(x; P, Q) (:func:`defop.operator.movable
    .fit_movable`).

    Returns
    -------
    op : defop.operator.movable.MovableOp
    record : MovableRecord
    """
    en.check_energy(energy)
    m = opt.integer("m", m, minimum=2)
    n_q = opt.integer("n_q", n_q, minimum=1)
    opt.seed(seed)
    check_placement(shape, placement)
    t0 = time.perf_counter()
    idx, Q = sample_joint(shape, placement, -(-m // n_q), np.random.default_rng(seed), n_q)
    X, conv = solve_joint(shape, placement, idx, Q, energy, n_jobs, progress, cache)
    if not conv.all():
        warnings.warn(
            f"{int((~conv).sum())} of {len(conv)} joint solves did not converge; used as they are",
            NotConvergedWarning,
            stacklevel=2,
        )
    meta = {"shape": shape.name, "energy": energy, "seed": seed}
    op = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X, meta)
    return op, MovableRecord(idx, Q, X, conv, time.perf_counter() - t0)
