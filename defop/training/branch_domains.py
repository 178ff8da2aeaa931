"""Certified presence and absence of each branch at the samples, and the folds between them (§5, issue 37).

Discovery (:func:`defop.training.branches.discover`) finds a branch b at the samples its starts happened to reach;
it says nothing about the samples where b was not found: b may be absent there (beyond its fold) or merely missed.
:func:`certify` decides every sample that borders b's domain on the grid (a 4-neighbour of a sample holding b):

* **present** when one solve at Q_j warm-started from b's minimum at a neighbour Q_k (the nearest minimum of b)
  stays on b: it verifies, no vertex moves more than ``FOLLOW_RATIO`` × the handles' step (no jump), and its
  score stays on b's side of the threshold t(Q) (:func:`defop.training.branches.group`). The minimum joins b,
  and the new neighbours of b are certified in turn (a flood fill: discovery's missed samples are found);
* **absent** when that solve leaves b (it jumps by the ``FOLLOW_RATIO`` rule, or lands on the other side);
* **uncertified** when the solve does not verify (reported; the domain fit treats it as absent).

Between every present sample k and absent neighbour j, :func:`bracket_fold` bisects the segment Q_k → Q_j
(``levels`` warm-started solves) to an interval of 2^−levels of the spacing that holds b's edge; its midpoint is
a **fold point** of b (the edge of b's domain: a fold, or where b's score meets the other sheet's). The last
point still on b adds a minimum to b (``edges``).
:func:`defop.operator.domains.domain_values` turns the labels into the signed distance
to b's fold points, which :mod:`defop.operator.branched` interpolates (module docstring there). Every solve here
counts in the multi-valued training's cost (``Branches.certify_seconds``).

Scope: a 2D grid of displacements of one moving handle (or of a patch of handles moved together,
:func:`defop.training.branches.grid_samples`). Several handles moving independently span a space of more than two
dimensions, which a grid's 4-neighbours do not cover: :func:`certify` raises ValueError for it.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import options as opt
from ..operator.domains import fold_pairs
from ..variational.solver import Solver
from .branches import FOLLOW_RATIO, _rms, _solve, grid_spacing, plane

__all__ = ["Certified", "bracket_fold", "certify", "certify_branches", "grid_neighbours"]


def grid_neighbours(Q):
    """The 4-neighbours (within 1.01 h, :func:`grid_spacing`) of each sample: a list of (·,) int arrays."""
    flat = np.asarray(Q).reshape(len(Q), -1)
    D = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    h = grid_spacing(Q)
    return [np.flatnonzero((D[k] <= 1.01 * h) & (D[k] > 0)) for k in range(len(Q))]


def _span_check(Q):
    flat = np.asarray(Q).reshape(len(Q), -1)
    s = np.linalg.svd(flat - flat.mean(axis=0), compute_uv=False)
    if len(s) > 2 and s[2] > 1e-9 * max(s[0], 1e-300):
        raise ValueError(
            "samples must be a 2D grid of one handle's (or a patch's common) displacement: certify covers one moving "
            f"handle, and these samples span {int((s > 1e-9 * s[0]).sum())} dimensions"
        )


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
        self.mass = shape.mesh.mass_matrix.diagonal()
        self.u, self.t = branches.mode, branches.threshold

    def side(self, X, Q):
        if not np.any(self.u):
            return 1
        s = float(np.einsum("v,vc,vc->", self.mass, X - self.shape.mesh.V, self.u))
        return 1 if s - plane(self.t, Q, self.shape.P_moving) >= 0 else -1

    def step(self, q0, q1, X0, side):
        """(X, E, verdict) of the solve at q1 from X0 (b's minimum at q0): verdict True (stays), False (leaves),
        None (did not verify)."""
        X, E, ok = _solve(self.solver, self.shape.targets(q1), X0, "local")
        if not ok:
            return X, E, None
        moved = np.abs(X - X0).max() <= FOLLOW_RATIO * np.abs(q1 - q0).max()
        return X, E, bool(moved and self.side(X, q1) == side)


def bracket_fold(judge, qa, qb, Xa, Ea, side, levels):
    """Bisect qa (b present, minimum Xa) → qb (b absent) ``levels`` times: (fold point, (q, X, E) last on b).

    Each half step is one solve warm-started from the last minimum on b; an unverified solve counts as leaving.
    """
    lo, hi, X_lo, E_lo = qa, qb, Xa, Ea
    for _ in range(levels):
        mid = (lo + hi) / 2
        X, E, stays = judge.step(lo, mid, X_lo, side)
        if stays:
            lo, X_lo, E_lo = mid, X, E
        else:
            hi = mid
    return (lo + hi) / 2, (lo, X_lo, E_lo)


def _certify_branch(judge, shape, Q, nbrs, b, known, tol, levels):
    """:class:`Certified` of one branch (module docstring): flood fill over the border, then bisection."""
    grid = len(nbrs)
    c = Certified({int(k): (X, E) for k, X, E in zip(b.samples, b.X, b.energy) if k < grid})
    todo = sorted({int(j) for k in c.present for j in nbrs[k] if j not in c.present})
    done = set()
    while todo:
        j = todo.pop(0)
        if j in done or j in c.present:
            continue
        done.add(j)
        k = min((k for k in nbrs[j] if k in c.present), key=lambda k: np.linalg.norm(Q[k] - Q[j]))
        X, E, stays = judge.step(Q[k], Q[j], c.present[k][0], b.side)
        if stays is None:
            c.uncertified.append(j)
            continue
        if stays:
            c.present[j] = (X, E)
            c.found += 1
            todo += [int(i) for i in nbrs[j] if i not in c.present and i not in done]
            continue
        c.absent.append(j)
        if all(_rms(shape.mesh, X - Y) > tol * shape.mesh.bbox_diagonal for Y in known[j]) and len(known[j]) >= 2:
            c.third.append(j)
    lows = []
    for j in c.absent:
        for k in nbrs[j]:
            if k in c.present:
                fold, low = bracket_fold(judge, Q[k], Q[j], *c.present[k], b.side, levels)
                c.folds.append(fold)
                c.fold_edges.append((int(k), int(j)))
                lows.append(low)
                if not np.array_equal(low[0], Q[k]):
                    c.edges.append(low)
    c.segments = refine_segments(judge, Q, c, lows, b.side, levels)
    return c


def refine_segments(judge, Q, c, lows, side, levels):
    """The edge of b's domain as segments (s, 2, n_moving, d): in each grid cell the two fold points on its edges
    (marching squares, :func:`defop.operator.domains.fold_segments`), split at one more fold point bisected across
    the segment's middle (from h/4 inside to h/4 outside, ``levels`` solves, started from the nearer fold's last
    minimum on b). Where that start leaves b, the segment stays whole."""
    if not c.folds:
        return np.zeros((0, 2, *Q.shape[1:]))
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
        Xs, Es, stays = judge.step(q0, qs, X0, side)
        if not stays:
            out.append((folds[a], folds[b]))
            continue
        fold, _ = bracket_fold(judge, qs, qe, Xs, Es, side, levels)
        c.folds_inner.append(fold)
        out += [(folds[a], fold), (fold, folds[b])]
    return np.asarray(out).reshape(-1, 2, *Q.shape[1:])


def certify(shape, branches, levels=3, tol=1e-3, energy="sarap"):
    """Certify every branch's presence and absence at the grid samples bordering its domain (module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    branches : defop.training.branches.Branches
        From :func:`defop.training.branches.group` on a grid (:func:`defop.training.branches.grid_samples`).
    levels : int
        Bisection steps towards each fold (to 2^−levels of the spacing).
    tol : float
        Minima closer than ``tol`` × bbox diagonal (M-weighted RMS) are one (as ``group``).
    energy : str

    Returns
    -------
    certified : list of Certified
        One per branch, in label order.
    seconds : float
        CPU seconds of every solve here (``time.process_time``).
    """
    levels = opt.integer("levels", levels, minimum=0, maximum=12)
    tol = opt.positive("tol", tol)
    Q = np.asarray(branches.samples)
    grid = len(branches.distinct)  # the grid samples (edge minima of refine_folds come after them)
    _span_check(Q[:grid])
    t0 = time.process_time()
    judge = _Judge(shape, branches, Solver(shape.mesh, shape.handles, energy=energy))
    nbrs = grid_neighbours(Q[:grid])
    known = [[] for _ in range(grid)]
    for b in branches.branches:
        for k, X in zip(b.samples, b.X):
            if k < grid:
                known[k].append(X)
    out = [_certify_branch(judge, shape, Q[:grid], nbrs, b, known, tol, levels) for b in branches.branches]
    return out, time.process_time() - t0


def certify_branches(shape, branches, levels=3, edges=True, tol=1e-3, energy="sarap"):
    """:func:`certify`, applied: Branches whose branches hold every certified-present grid sample, their fold
    points, absent and uncertified samples, and (``edges``) the last minimum of each bisection as a new sample.

    Returns
    -------
    defop.training.branches.Branches
        ``grid`` the number of grid samples (edge minima after them, each on one branch: ``distinct`` 1 and
        ``lowest`` that branch there; on the grid ``distinct`` counts the branches certified present too),
        ``certify_seconds`` the CPU seconds of the solves, ``third`` the samples with more than two minima seen,
        ``found`` the samples discovery had missed.
    """
    certified, seconds = certify(shape, branches, levels, tol, energy)
    Q = np.asarray(branches.samples)
    grid = len(branches.distinct)
    extra_Q, out, lowest = [], [], []
    for b, c in zip(branches.branches, certified):
        ks = np.array(sorted(c.present), dtype=np.int64)
        add = c.edges if edges else []
        idx = grid + len(extra_Q) + np.arange(len(add), dtype=np.int64)
        extra_Q += [e[0] for e in add]
        lowest += [b.label] * len(add)
        X = np.concatenate([[c.present[k][0] for k in ks], [e[1] for e in add]]).reshape(-1, *b.X.shape[1:])
        E = np.array([c.present[k][1] for k in ks] + [e[2] for e in add])
        margin = np.full(len(E), np.nan)
        old = dict(zip(b.samples.tolist(), b.margin))
        margin[: len(ks)] = [old.get(int(k), np.nan) for k in ks]
        folds = np.asarray(c.folds, dtype=float).reshape(-1, *Q.shape[1:])
        absent, unc = (np.array(sorted(a), dtype=np.int64) for a in (c.absent, c.uncertified))
        out.append(
            dataclasses.replace(
                b,
                samples=np.concatenate([ks, idx]),
                X=X,
                energy=E,
                margin=margin,
                folds=np.concatenate([folds, np.reshape(c.folds_inner, (-1, *Q.shape[1:]))]),
                segments=c.segments,
                absent=absent,
                uncertified=unc,
            )
        )
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
