"""A branch's domain in closed form, fitted from both sides, and the box of its samples (§5).

Branch b of a multi-valued operator exists where its domain function is positive:

    g_b(Q) = Ψ_D(Q) · w_D                         (a TPS on R^{dn}, its own centres)

fitted by interpolation (problem (8)'s structure, :func:`defop.operator.fit.structure`) to the signed distance to
b's fold points: + at the grid samples where b is present (discovered or certified), − at every other sample
(certified absent: a solve warm-started from b left b; or beyond the certified border), 0 at the fold points
(bisected to 2^−levels of the spacing between a present and an absent neighbour,
:mod:`defop.training.branch_domains`). Why this and not the stability margin λ²_b alone: λ² is known only where
b exists, so its fit extrapolates past the fold with nothing to pin it below zero (on a slanted bistable shape
it stayed positive 20 frames past the fold), and it vanishes at a fold, not where b's score meets the other
sheet's. The signed distance is defined on both sides, is zero exactly at the certified edge, and, the fit being
an interpolant, its sign agrees with every certified label on the grid; near a smooth fold it is about linear in
Q, which the TPS reproduces exactly, so its zero set runs through the fold points. It needs no eigenvalue solve.

Files of format ``defop-branched-1`` carry λ²_b (Ψ_b(Q) · l_b) as the domain function instead: it is read as a
:class:`Domain` whose basis is the branch operator's Ψ_b, evaluated as every domain is (nothing here fits λ²).

Far from the data: :func:`outside_box` flags a Q outside the samples' box (per coordinate of Q − P) enlarged by one
grid spacing; every branch path warns there (:class:`defop.operator.defop.ExtrapolationWarning`), whatever g_b does.
"""

from __future__ import annotations

import numpy as np

from .fit import structure
from .handle_bases import make_basis

__all__ = ["Domain", "box_of", "domain_values", "fit_domain", "fold_pairs", "outside_box"]


class Domain:
    """g(Q) = Ψ_D(Q) · w: a branch's domain function (> 0 where the branch exists).

    Parameters
    ----------
    basis : defop.operator.handle_bases.HandleBasis
    w : (|Ψ_D|,) numpy array
    own : bool
        True when Ψ_D is the domain's own basis (format 2); False when it is the branch operator's Ψ_b and w its
        λ²_b coefficients (format 1): how a file stores it, not how it is evaluated.
    """

    def __init__(self, basis, w, own=True):
        self.basis = basis
        self.w = np.asarray(w, dtype=float)
        self.own = bool(own)
        if self.w.shape != (basis.size,) or not np.isfinite(self.w).all():
            raise ValueError(f"domain weights must be {basis.size} finite coefficients, got {self.w.shape}")

    def __call__(self, Q, psi=None):
        """g(Q): float or (k,) for Q (n_moving, d) or (k, n_moving, d); ``psi``: Ψ_D(Q) when already evaluated."""
        return (self.basis(Q) if psi is None else psi) @ self.w

    def __repr__(self):
        return f"Domain({self.basis.kind}, {self.basis.size} functions, {'own' if self.own else 'λ² on Ψ_b'})"


def fit_domain(P, scale, points, values):
    """The :class:`Domain` interpolating ``values`` at ``points`` (TPS centred at the points; module docstring).

    Parameters
    ----------
    P : (n_moving, d) numpy array
    scale : float
        The normalising length of Ψ (the branch operator's).
    points : (m, n_moving, d) numpy array
    values : (m,) numpy array, or None
        None: the branch exists everywhere (g = 1, a TPS on P alone).

    Returns
    -------
    Domain
    """
    P = np.asarray(P, dtype=float)
    if values is None:
        basis = make_basis("tps", P, P[None], scale)
        w = np.zeros(basis.size)
        w[0] = 1.0
        return Domain(basis, w)
    values = np.asarray(values, dtype=float)
    points = np.asarray(points, dtype=float)
    if values.shape != (len(points),) or not np.isfinite(values).all():
        raise ValueError(f"values must be {len(points)} finite numbers, one per point, got {values.shape}")
    basis = make_basis("tps", P, points, scale)
    G, beta = structure(basis, points)
    return Domain(basis, G @ values + beta * values[0])


def box_of(P, samples, spacing):
    """(2, dn): the lowest and highest Q − P (flattened) over ``samples`` (m, n_moving, d), ± ``spacing``."""
    D = (np.asarray(samples, dtype=float) - P).reshape(len(samples), -1)
    return np.stack([D.min(axis=0) - spacing, D.max(axis=0) + spacing])


def outside_box(box, P, Q):
    """(k,) bool (or a bool for one Q): Q − P outside ``box`` in some coordinate."""
    Q = np.asarray(Q, dtype=float)
    D = (Q - P).reshape(-1, box.shape[1])
    out = ((D < box[0]) | (D > box[1])).any(axis=1)
    return out if Q.ndim == 3 else bool(out[0])


#: where on each segment of the edge the domain function is pinned to zero (besides its two fold points)
SEGMENT_POINTS = (0.25, 0.5, 0.75)


def _grid_coords(flat, h):
    """Integer coordinates (m, 2) of samples (m, D) on a square grid of spacing h (its two edge directions)."""
    D = flat[:, None] - flat[None]
    dist = np.linalg.norm(D, axis=-1)
    pairs = np.argwhere(np.abs(dist - h) <= 0.01 * h)
    e1 = D[pairs[0][1], pairs[0][0]] / h
    other = [D[j, i] / h for i, j in pairs if abs(np.dot(D[j, i] / h, e1)) < 0.5]
    e2 = other[0] if other else np.zeros_like(e1)
    X = flat - flat[0]
    return np.stack([np.round(X @ e1 / h), np.round(X @ e2 / h)], axis=1).astype(np.int64)


def fold_pairs(Q, folds, edges):
    """The edge of a domain inside each grid cell (marching squares): pairs (i, j) of fold points on a cell's edges
    (two per cell; with four, the pairing of least total length). ``edges`` (f, 2): the grid edge of each fold."""
    flat = np.asarray(Q, dtype=float).reshape(len(Q), -1)
    F = np.asarray(folds, dtype=float).reshape(len(folds), -1)
    h = float(np.min([np.linalg.norm(flat[k] - flat[j]) for k, j in edges]))
    ij = _grid_coords(flat, h)
    at = {tuple(c): k for k, c in enumerate(ij.tolist())}
    on = {frozenset((int(k), int(j))): f for f, (k, j) in enumerate(edges)}
    pairs = []
    for i, j in at:
        c = [at.get((i + a, j + b)) for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
        if None in c:
            continue
        fs = [on[e] for e in (frozenset((c[t], c[(t + 1) % 4])) for t in range(4)) if e in on]
        if len(fs) == 2:
            pairs.append((fs[0], fs[1]))
        elif len(fs) == 4:
            a = np.linalg.norm(F[fs[0]] - F[fs[1]]) + np.linalg.norm(F[fs[2]] - F[fs[3]])
            b = np.linalg.norm(F[fs[1]] - F[fs[2]]) + np.linalg.norm(F[fs[3]] - F[fs[0]])
            pairs += [(fs[0], fs[1]), (fs[2], fs[3])] if a <= b else [(fs[1], fs[2]), (fs[3], fs[0])]
    return pairs


def _distance(points, segs, F):
    """Distance (m,) from points (m, D) to the segments (s, 2, D) and the points F (f, D)."""
    d = np.linalg.norm(points[:, None] - F[None], axis=-1).min(axis=1)
    for a, b in segs:
        t = np.clip((points - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-300), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(points - (a + t[:, None] * (b - a)), axis=1))
    return d


def domain_values(Q, present, folds, segments=None):
    """The points and values of a branch's domain function: the signed distance to its edge.

    Parameters
    ----------
    Q : (m, n_moving, d) numpy array
        The grid samples.
    present : (p,) int array
        Indices of the samples holding the branch.
    folds : (f, n_moving, d) numpy array
        Its fold points.
    segments : (s, 2, n_moving, d) numpy array, optional
        The edge between the fold points (:func:`defop.training.branch_domains.refine_segments`).

    Returns
    -------
    points : (m + f + 3 s, n_moving, d) numpy array
        Every grid sample, the fold points, then :data:`SEGMENT_POINTS` on each segment.
    values : (m + f + 3 s,) numpy array or None
        + the distance to the edge (segments and fold points) at the samples holding the branch, − at every other
        sample, 0 on the edge. None when there is no fold point (the branch is everywhere it was seen).
    """
    Q = np.asarray(Q, dtype=float)
    folds = np.asarray(folds, dtype=float).reshape(-1, *Q.shape[1:])
    if not len(folds):
        return Q, None
    flat, F = Q.reshape(len(Q), -1), folds.reshape(len(folds), -1)
    segs = np.zeros((0, 2, F.shape[1])) if segments is None else np.asarray(segments).reshape(-1, 2, F.shape[1])
    pins = np.concatenate([(1 - t) * segs[:, 0] + t * segs[:, 1] for t in SEGMENT_POINTS])
    d = _distance(flat, segs, F)
    sign = np.where(np.isin(np.arange(len(Q)), np.asarray(present)), 1.0, -1.0)
    points = np.concatenate([Q, folds, pins.reshape(-1, *Q.shape[1:])])
    return points, np.concatenate([sign * d, np.zeros(len(F) + len(pins))])
