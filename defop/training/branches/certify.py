"""Certified presence and absence of each branch at the samples, and the folds between them (§5).

Discovery (:func:`defop.training.branches.discover`) finds a branch b at the samples its starts happened to reach;
it says nothing about the samples where b was not found: b may be absent there (beyond its fold) or merely missed.
:func:`certify` decides every sample that borders b's domain on the grid (a 4-neighbour of a sample holding b):

* **present** when one solve at Q_j warm-started from b's minimum at a neighbour Q_k (the nearest minimum of b)
  stays on b: it verifies, no vertex moves more than :data:`FOLLOW_RATIO` × the handles' step (no jump), and its
  score stays on b's side of the threshold t(Q) (:func:`defop.training.branches.group`). The minimum joins b,
  and the new neighbours of b are certified in turn (a flood fill: discovery's missed samples are found);
* **absent** when that solve leaves b (it jumps by the :data:`FOLLOW_RATIO` rule, or lands on the other side);
* **uncertified** when the solve does not verify (reported; the domain fit treats it as absent).

Between every present sample k and absent neighbour j, :func:`bracket_fold` bisects the segment Q_k → Q_j
(``depth`` warm-started solves, :func:`bisect`) to an interval of 2^−depth of the spacing that holds b's edge; its
midpoint is a **fold point** of b (the edge of b's domain: a fold, or where b's score meets the other sheet's). The
last point still on b adds a minimum to b (``edges``). :func:`defop.operator.domains.domain_values` turns the labels
into the signed distance to b's fold points, which :mod:`defop.operator.branched` interpolates. Every solve here
counts in the multi-valued training's cost (``certify_seconds``).

The flood fills of the branches, then all the bisections, then all the segments' bisections are independent of
each other: each stage runs on the sample engine as paths of solves (:func:`defop.training.paths.walks`: each
step of a path is one warm-started solve, the next chosen by the last), and the result does not depend on the
number of workers.

Scope: a 2D grid of displacements of one moving handle (or of a patch of handles moved together,
:func:`defop.training.branches.grid_samples`). Several handles moving independently span a space of more than two
dimensions, which a grid's 4-neighbours do not cover: :func:`certify` raises ValueError for it.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np

from ... import options as opt
from ...operator.domains import fold_pairs
from ...variational.solver import Solver
from .. import batch, paths
from .. import cache as cache_mod
from ..minima import rms
from . import records
from .grid import check_planar, grid_neighbours
from .group import check_mesh, plane, score

__all__ = [
    "FOLLOW_RATIO",
    "Certified",
    "bisect",
    "bracket_fold",
    "certify",
    "certify_branches",
    "is_certified",
    "refine_segments",
]

#: a warm-started step whose minimum moves a vertex more than this many times the handles' step left the branch
#: (it jumped)
FOLLOW_RATIO = 4.0


@dataclasses.dataclass
class Certified:
    """One branch's labels on the grid after :func:`certify`.

    Attributes
    ----------
    present : dict of int -> (X (n_vertices, d), E)
        The grid samples holding b (discovered or certified), with b's minimum there.
    absent : list of int
        Grid samples certified absent (a solve from b left b).
    uncertified : list of int
        Bordering samples whose solve did not verify (neither label).
    folds : list of (n_moving, d) numpy arrays
        Fold points: midpoints of the bisected intervals between present and absent neighbours.
    fold_edges : list of (int, int)
        The grid edge (present sample, absent sample) of each fold point.
    folds_inner : list of (n_moving, d) numpy arrays
        Fold points bisected across the middle of a cell's segment (:func:`refine_segments`).
    segments : (s, 2, n_moving, d) numpy array
        The edge of b's domain between the fold points (:func:`refine_segments`).
    edges : list of (Q, X, E)
        The last point on b of each bisection (a minimum of b).
    found : int
        Samples certified present that discovery had missed.
    third : list of int
        Grid samples where a certification solve landed on a verified minimum distinct from every minimum known
        there (with b's and the other branch's: more than two minima at that Q).
    """

    present: dict
    absent: list = dataclasses.field(default_factory=list)
    uncertified: list = dataclasses.field(default_factory=list)
    folds: list = dataclasses.field(default_factory=list)
    fold_edges: list = dataclasses.field(default_factory=list)
    folds_inner: list = dataclasses.field(default_factory=list)
    segments: np.ndarray = None
    edges: list = dataclasses.field(default_factory=list)
    found: int = 0
    third: list = dataclasses.field(default_factory=list)


class _Judge:
    """One warm-started step and its verdict: stays on b (verified, no jump, b's side) or not."""

    def __init__(self, shape, branches, solver):
        self.shape, self.solver = shape, solver
        self.u, self.t = branches.mode, branches.threshold

    def side(self, X, Q):
        if not np.any(self.u):
            return 1
        s = score(self.shape.mesh, self.u, X)
        return 1 if s - plane(self.t, Q, self.shape.P_moving) >= 0 else -1

    def step(self, q0, q1, X0, side):
        """A path of one solve (:func:`defop.training.paths.walk`): at q1 from X0 (b's minimum at q0); returns
        (X, E, verdict), verdict True (stays), False (leaves), None (did not verify)."""
        X, E, ok = yield self.shape.targets(q1), X0
        if not ok:
            return X, E, None
        moved = np.abs(X - X0).max() <= FOLLOW_RATIO * np.abs(q1 - q0).max()
        return X, E, bool(moved and self.side(X, q1) == side)


def depth_of(depth, levels, default=3):
    """The bisection depth from ``depth=`` or its old name ``levels=`` (which warns)."""
    if levels is not None:
        if depth is not None:
            raise TypeError("pass depth= only (levels= is its old name)")
        warnings.warn(
            "levels= is renamed depth= (the bisection's steps towards each fold)",
            DeprecationWarning,
            stacklevel=opt.user_stacklevel(),
        )
        depth = levels
    return opt.integer("depth", default if depth is None else depth, minimum=0, maximum=12)


def bisect(step, lo, hi, X_lo, E_lo, depth):
    """The bisection of branch edges: halve the segment lo (on the branch, minimum X_lo) → hi ``depth`` times. A path
    for :func:`defop.training.paths.walk` (it returns what is listed below).

    Parameters
    ----------
    step : callable
        ``step(q0, q1, X0)``: the path (:func:`defop.training.paths.walk`) of one solve at q1 warm-started from the
        minimum X0 at q0, returning (X, E, stays): whether it stays on the branch (True; False or None leave it).
    lo, hi : (n_moving, d) numpy arrays
    X_lo : (n_vertices, d) numpy array
    E_lo : float
    depth : int

    Returns
    -------
    lo, hi : (n_moving, d) numpy arrays
        The last interval: lo on the branch, hi off it.
    X_lo, E_lo
        The minimum at lo.
    moved : bool
        Whether any half step stayed on the branch.
    """
    moved = False
    for _ in range(depth):
        mid = (lo + hi) / 2
        X, E, stays = yield from step(lo, mid, X_lo)
        if stays:
            lo, X_lo, E_lo, moved = mid, X, E, True
        else:
            hi = mid
    return lo, hi, X_lo, E_lo, moved


def bracket_fold(judge, qa, qb, Xa, Ea, side, depth=None, *, levels=None):
    """Bisect qa (b present, minimum Xa) → qb (b absent) ``depth`` times (:func:`bisect`): (fold point, (q, X, E)
    last on b). Each half step is one solve warm-started from the last minimum on b; an unverified solve counts as
    leaving. Run by the sample engine: ``paths.walk(judge.solver, bracket_fold(judge, ...))``."""
    depth = depth_of(depth, levels)
    lo, hi, X, E, _ = yield from bisect(lambda q0, q1, X0: judge.step(q0, q1, X0, side), qa, qb, Xa, Ea, depth)
    return (lo + hi) / 2, (lo, X, E)


def _flood(judge, Q, nbrs, b, known, tol):
    """b's :class:`Certified` labels on the grid (module docstring): a flood fill over its border, as a path of
    solves for :func:`defop.training.paths.walk`."""
    grid, mesh = len(nbrs), judge.shape.mesh
    c = Certified({int(k): (X, E) for k, X, E in zip(b.samples, b.X, b.energy) if k < grid})
    todo = sorted({int(j) for k in c.present for j in nbrs[k] if j not in c.present})
    done = set()
    while todo:
        j = todo.pop(0)
        if j in done or j in c.present:
            continue
        done.add(j)
        k = min((k for k in nbrs[j] if k in c.present), key=lambda k: np.linalg.norm(Q[k] - Q[j]))
        X, E, stays = yield from judge.step(Q[k], Q[j], c.present[k][0], b.side)
        if stays is None:
            c.uncertified.append(j)
            continue
        if stays:
            c.present[j] = (X, E)
            c.found += 1
            todo += [int(i) for i in nbrs[j] if i not in c.present and i not in done]
            continue
        c.absent.append(j)
        if all(rms(mesh, X - Y) > tol * mesh.bbox_diagonal for Y in known[j]) and len(known[j]) >= 2:
            c.third.append(j)
    return c


def _flood_item(judge, Q, nbrs, known, tol, b):
    return (yield from _flood(judge, Q, nbrs, b, known, tol))


def _bracket_item(judge, depth, item):
    qa, qb, Xa, Ea, side = item
    return (yield from bracket_fold(judge, qa, qb, Xa, Ea, side, depth))


def _segment_item(judge, depth, item):
    q0, X0, qs, qe, side = item
    Xs, Es, stays = yield from judge.step(q0, qs, X0, side)
    if not stays:
        return None
    return (yield from bracket_fold(judge, qs, qe, Xs, Es, side, depth))[0]


def _brackets(judge, Q, nbrs, certified, branches, depth, n_jobs):
    """Every (present, absent) grid edge of every branch bisected: fold points, their edges and the last minima."""
    items, owner = [], []
    for i, (b, c) in enumerate(zip(branches, certified)):
        for j in c.absent:
            for k in nbrs[j]:
                if k in c.present:
                    items.append((Q[k], Q[j], *c.present[k], b.side))
                    owner.append((i, int(k), int(j)))
    path = functools.partial(_bracket_item, judge, depth)
    results, seconds = paths.walks(judge.solver, path, items, n_jobs, desc="fold bisections")
    lows = [[] for _ in certified]
    for (i, k, j), (fold, low) in zip(owner, results):
        c = certified[i]
        c.folds.append(fold)
        c.fold_edges.append((k, j))
        lows[i].append(low)
        if not np.array_equal(low[0], Q[k]):
            c.edges.append(low)
    return lows, seconds


def segment_starts(Q, c, lows):
    """The cross-cell bisections of :func:`refine_segments`: per pair of fold points of a cell (marching squares,
    :func:`defop.operator.domains.fold_pairs`), (a, b, (q0, X0, qs, qe)): from the nearer fold's last minimum on b
    (q0, X0), a segment across the middle of the pair from h/4 inside (qs) to h/4 outside (qe)."""
    folds = np.asarray(c.folds)
    flat = folds.reshape(len(folds), -1)
    h = float(np.linalg.norm((Q[c.fold_edges[0][0]] - Q[c.fold_edges[0][1]]).ravel()))
    out = []
    for a, b in fold_pairs(Q, folds, c.fold_edges):
        t = (flat[b] - flat[a]) / max(np.linalg.norm(flat[b] - flat[a]), 1e-300)
        mid = (flat[a] + flat[b]) / 2
        v = mid - Q[c.fold_edges[a][0]].ravel()  # from a's present corner: towards the absent side
        n = v - (v @ t) * t
        n /= max(np.linalg.norm(n), 1e-300)
        qs, qe = ((mid + s * 0.25 * h * n).reshape(Q.shape[1:]) for s in (-1, 1))
        q0, X0, _ = lows[a]
        out.append((a, b, (q0, X0, qs, qe)))
    return out


def refine_segments(judge, Q, certified, lows, sides, depth, n_jobs=None):
    """The edge of each branch's domain as segments (s, 2, n_moving, d), set on each :class:`Certified`: in each
    grid cell the two fold points on its edges, split at one more fold point bisected across the segment's middle
    (:func:`segment_starts`, ``depth`` solves). Where the start leaves b, the segment stays whole.

    Returns
    -------
    seconds : float
        CPU seconds of the solves.
    """
    items, owner = [], []
    for i, c in enumerate(certified):
        if c.folds:
            for a, b, (q0, X0, qs, qe) in segment_starts(Q, c, lows[i]):
                items.append((q0, X0, qs, qe, sides[i]))
                owner.append((i, a, b))
    path = functools.partial(_segment_item, judge, depth)
    results, seconds = paths.walks(judge.solver, path, items, n_jobs, desc="edge bisections")
    out = [[] for _ in certified]
    for (i, a, b), fold in zip(owner, results):
        F = certified[i].folds
        if fold is None:
            out[i].append((F[a], F[b]))
            continue
        certified[i].folds_inner.append(fold)
        out[i] += [(F[a], fold), (fold, F[b])]
    for c, segs in zip(certified, out):
        c.segments = np.asarray(segs).reshape(-1, 2, *Q.shape[1:])
    return seconds


def certify(shape, branches, depth=None, tol=1e-3, energy="sarap", n_jobs=None, cache=True, *, levels=None):
    """Certify every branch's presence and absence at the grid samples bordering its domain (module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    branches : defop.training.branches.SampledBranches
        From :func:`defop.training.branches.group` on a grid (:func:`defop.training.branches.grid_samples`).
    depth : int
        Bisection steps towards each fold (to 2^−depth of the spacing; default 3). ``levels=``: its old name.
    tol : float
        Minima closer than ``tol`` × bbox diagonal (M-weighted RMS) are one (as ``group``).
    energy : str
    n_jobs : int, optional
        Workers (:func:`defop.training.batch.parallel_map`; the result does not depend on it).
    cache : bool
        Store/reuse the result under ``config.cache_dir()`` (:mod:`defop.training.branches.records`).

    Returns
    -------
    certified : list of Certified
        One per branch, in label order.
    seconds : float
        CPU seconds of every solve here (``time.process_time`` of the processes that solved; as measured when
        computed, for a cached result).
    """
    depth = depth_of(depth, levels)
    tol = opt.positive("tol", tol)
    check_mesh(shape, branches)
    store = cache_mod.open_cache(cache)
    grid = branches.grid if branches.grid is not None else len(branches.distinct)  # edge minima follow the grid
    Q = np.asarray(branches.samples)[:grid]
    check_planar(Q)
    solver = Solver(shape.mesh, shape.handles, energy=energy)
    qshape, xshape = Q.shape[1:], shape.mesh.V.shape
    key = None if store is None else records.certified_key(shape, branches, grid, depth, tol, solver)

    def compute():
        out, seconds = _certify(shape, branches, Q, _Judge(shape, branches, solver), depth, tol, n_jobs)
        return records.to_arrays(out, seconds, qshape, xshape)

    expect = records.expected(len(branches.branches), qshape, xshape)
    z = batch.load_or_compute(store, "branch-certified", key, expect, compute)
    return records.from_arrays(z, len(branches.branches), Certified)


def _certify(shape, branches, Q, judge, depth, tol, n_jobs):
    """:func:`certify`'s work: the flood fills, the fold bisections and the segments' bisections."""
    nbrs = grid_neighbours(Q)
    known = [[] for _ in range(len(Q))]
    for b in branches.branches:
        for k, X in zip(b.samples, b.X):
            if k < len(Q):
                known[k].append(X)
    flood = functools.partial(_flood_item, judge, Q, nbrs, known, tol)
    out, s0 = paths.walks(judge.solver, flood, branches.branches, n_jobs, desc="certification")
    lows, s1 = _brackets(judge, Q, nbrs, out, branches.branches, depth, n_jobs)
    s2 = refine_segments(judge, Q, out, lows, [b.side for b in branches.branches], depth, n_jobs)
    return out, s0 + s1 + s2


def is_certified(branches):
    """Whether ``branches`` come from :func:`certify_branches` (a grid count, and fold points on every branch)."""
    return branches.grid is not None and all(b.folds is not None for b in branches.branches)


def certify_branches(
    shape, branches, depth=None, edges=True, tol=1e-3, energy="sarap", n_jobs=None, cache=True, *, levels=None
):
    """:func:`certify`, applied: branches that hold every certified-present grid sample, their fold points, absent
    and uncertified samples, and (``edges``) the last minimum of each bisection as a new sample.

    Certification is idempotent: certified branches (:func:`is_certified`) are returned as they are, so running it
    again (a notebook cell run twice) changes nothing. Parameters as :func:`certify`.

    Returns
    -------
    defop.training.branches.SampledBranches
        ``grid`` the number of grid samples (edge minima after them, each on one branch: ``distinct`` 1 and
        ``lowest`` that branch there; on the grid ``distinct`` counts the branches certified present too),
        ``certify_seconds`` the CPU seconds of the solves, ``third`` the samples with more than two minima seen,
        ``found`` the samples discovery had missed.
    """
    depth = depth_of(depth, levels)
    opt.positive("tol", tol)
    check_mesh(shape, branches)
    if is_certified(branches):
        return branches
    certified, seconds = certify(shape, branches, depth, tol, energy, n_jobs, cache)
    Q = np.asarray(branches.samples)
    grid = branches.grid if branches.grid is not None else len(branches.distinct)
    extra_Q, out, lowest = [], [], []
    for b, c in zip(branches.branches, certified):
        add = c.edges if edges else []
        idx = grid + len(extra_Q) + np.arange(len(add), dtype=np.int64)
        extra_Q += [e[0] for e in add]
        lowest += [b.label] * len(add)
        out.append(_certified_branch(b, c, add, idx, Q.shape[1:]))
    third = sorted(set(branches.third.tolist()) | {j for c in certified for j in c.third})
    seen = np.zeros(grid, int)  # distinct minima per grid sample: certification adds the branches discovery missed
    for c in certified:
        seen[list(c.present)] += 1
    return dataclasses.replace(
        branches,
        samples=np.concatenate([Q[:grid], np.reshape(extra_Q, (-1, *Q.shape[1:]))]),
        branches=out,
        distinct=np.concatenate([np.maximum(branches.distinct[:grid], seen), np.ones(len(extra_Q), int)]),
        lowest=np.concatenate([branches.lowest[:grid], lowest]).astype(branches.lowest.dtype),
        certify_seconds=branches.certify_seconds + seconds,
        grid=grid,
        third=np.array(third, dtype=np.int64),
        found=sum(c.found for c in certified),
    )


def _certified_branch(b, c, add, idx, qshape):
    """Branch b with its certified labels (:class:`Certified` c) and the edge minima ``add`` at samples ``idx``."""
    ks = np.array(sorted(c.present), dtype=np.int64)
    X = np.array([c.present[k][0] for k in ks] + [e[1] for e in add], dtype=float).reshape(-1, *b.X.shape[1:])
    E = np.array([c.present[k][1] for k in ks] + [e[2] for e in add], dtype=float)
    margin = np.full(len(E), np.nan)
    old = dict(zip(b.samples.tolist(), b.margin))
    margin[: len(ks)] = [old.get(int(k), np.nan) for k in ks]
    folds = np.asarray(c.folds, dtype=float).reshape(-1, *qshape)
    absent, unc = (np.array(sorted(a), dtype=np.int64) for a in (c.absent, c.uncertified))
    return dataclasses.replace(
        b,
        samples=np.concatenate([ks, idx]),
        X=X,
        energy=E,
        margin=margin,
        folds=np.concatenate([folds, np.reshape(c.folds_inner, (-1, *qshape))]),
        segments=c.segments,
        absent=absent,
        uncertified=unc,
    )
