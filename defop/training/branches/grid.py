"""The samples of branch discovery: grids of one handle's (or a patch's) displacements, their scans and neighbours."""

from __future__ import annotations

import numpy as np

from ... import options as opt

__all__ = [
    "check_planar",
    "grid_neighbours",
    "grid_samples",
    "grid_spacing",
    "moving_set",
    "neighbour_pairs",
    "scan_order",
]


def moving_set(P, moving):
    """The moving handles ``moving`` names (an index or a sequence of indices into P's rows), as an int array."""
    idx = np.atleast_1d(np.asarray(moving))
    if idx.ndim != 1 or len(idx) == 0 or idx.dtype.kind not in "iu" or not ((idx >= 0) & (idx < len(P))).all():
        raise ValueError(f"moving must index the {len(P)} moving handles (an int or a sequence of ints): {moving!r}")
    if len(np.unique(idx)) != len(idx):
        raise ValueError(f"moving must not repeat a handle, got {moving!r}")
    return idx


def _plane_axes(axes, d):
    axes = np.asarray(axes)
    if axes.shape != (2,) or axes.dtype.kind not in "iu" or not ((axes >= 0) & (axes < d)).all() or axes[0] == axes[1]:
        raise ValueError(f"axes must be two different coordinate axes below {d}, got {axes.tolist()!r}")
    return axes


def grid_samples(shape, radius, n, moving=0, offset=(0.0, 0.0), axes=(0, 1)):
    """Q_k on an n × n grid of displacements of the moving handles ``moving`` (the others at rest), rows of y, then x.

    Every handle in ``moving`` is translated by the same displacement, in the plane of the coordinate ``axes``: in
    2D one handle in the plane; in 3D a patch of handles moved together (``plank_3d``'s end, Fig. 10 in 3D).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    radius : float
        Half width of the grid (displacements in [−radius, radius]²).
    n : int
        Points per side (≥ 2; odd puts the rest pose on the grid).
    moving : int or sequence of int
        Which moving handles.
    offset : (2,) sequence of float
        Displacement of the grid's centre from the rest position, along ``axes`` (default: centred at rest).
    axes : (2,) sequence of int
        The two coordinate axes of the grid's plane.

    Returns
    -------
    Q : (n², n_moving, d) numpy array
        Sample k = i n + j has the handles at p + offset + (xs[j], ys[i]) (along ``axes``).
    """
    n = opt.integer("n", n, minimum=2)
    radius = opt.positive("radius", radius)
    P = np.asarray(shape.P_moving, dtype=float)
    idx = moving_set(P, moving)
    axes = _plane_axes(axes, P.shape[1])
    offset = np.asarray(offset, dtype=float)
    if offset.shape != (2,) or not np.isfinite(offset).all():
        raise ValueError(f"offset must be a finite (2,) displacement, got {offset!r}")
    t = np.linspace(-radius, radius, n)
    gx, gy = np.meshgrid(t, t)
    D = np.zeros((n * n, P.shape[1]))
    D[:, axes] = offset + np.stack([gx.ravel(), gy.ravel()], axis=-1)
    Q = np.repeat(P[None], n * n, axis=0)
    Q[:, idx] += D[:, None]
    return Q


def scan_order(ny, nx, by="columns", reverse=False):
    """Flat sample indices (i nx + j) of a boustrophedon scan of a (ny, nx) grid by columns or by rows.

    By columns: column 0 is swept from the bottom (from the top with ``reverse``), column 1 the other way, ...
    By rows: row 0 from the left (the right with ``reverse``), row 1 the other way, ... Every step joins
    4-neighbours, as a user dragging the handle back and forth across the region. A sweep should cross the folds
    (:func:`defop.training.branches.discover`): by columns when they run across the columns (the bar), by rows
    otherwise (the U's arm).

    Returns
    -------
    order : (ny nx,) numpy int array
    """
    ny, nx = opt.integer("ny", ny, minimum=1), opt.integer("nx", nx, minimum=1)
    if by not in ("columns", "rows"):
        raise ValueError(f"by must be 'columns' or 'rows', got {by!r}")
    outer, inner = (nx, ny) if by == "columns" else (ny, nx)
    order = []
    for a in range(outer):
        forward = (a % 2 == 0) != bool(reverse)
        for b in range(inner) if forward else range(inner - 1, -1, -1):
            order.append(b * nx + a if by == "columns" else a * nx + b)
    return np.asarray(order, dtype=np.int64)


def _distances(Q):
    flat = np.asarray(Q).reshape(len(Q), -1)
    return np.linalg.norm(flat[:, None] - flat[None], axis=-1)


def _spacing(D):
    return float(D[D > 0].min()) if (D > 0).any() else 0.0


def grid_spacing(Q):
    """h: the smallest distance between two samples Q (m, n_moving, d) (flattened); 0 for fewer than two."""
    return _spacing(_distances(Q))


def grid_neighbours(Q):
    """The neighbours of each sample (within 1.01 h, :func:`grid_spacing`: a grid's 4-neighbours): a list of (·,)
    int arrays."""
    D = _distances(Q)
    h = _spacing(D)
    return [np.flatnonzero((D[k] <= 1.01 * h) & (D[k] > 0)) for k in range(len(Q))]


def neighbour_pairs(Q, members):
    """(k, j) pairs of neighbouring samples (:func:`grid_neighbours`) with k in ``members`` and j not."""
    inside = np.zeros(len(Q), bool)
    inside[members] = True
    nbrs = grid_neighbours(Q)
    return [(int(k), int(j)) for k in np.flatnonzero(inside) for j in nbrs[k] if not inside[j]]


def check_planar(Q):
    """Raise ValueError unless the samples Q (m, n_moving, d) span at most two dimensions (a grid of one handle's,
    or a patch's common, displacement: the 4-neighbours of :func:`grid_neighbours` cover it)."""
    flat = np.asarray(Q).reshape(len(Q), -1)
    s = np.linalg.svd(flat - flat.mean(axis=0), compute_uv=False)
    if len(s) > 2 and s[2] > 1e-9 * max(s[0], 1e-300):
        raise ValueError(
            "samples must be a 2D grid of one handle's (or a patch's common) displacement: certify covers one moving "
            f"handle, and these samples span {int((s > 1e-9 * s[0]).sum())} dimensions"
        )
