"""Measurements on trajectories (:mod:`defop.analysis.trajectories`): planarity, neighbour jumps, discontinuities,
range and overshoot (paper §3.1, Figs. 3, 5 and 10).

Everything here is pure computation on (ny, nx[, c]) fields over a :class:`~defop.analysis.trajectories.HandleGrid`.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "check_path",
    "discontinuities",
    "discontinuity_points",
    "jump_ratio",
    "max_jump",
    "neighbour_jumps",
    "path_jumps",
    "plane_fit_residual",
    "range_and_error",
]


def check_path(path, shape):
    """Raise unless ``path`` (k, 2) visits every point of a ``shape`` = (ny, nx) grid once, between 4-neighbours."""
    ny, nx = shape
    if path.ndim != 2 or path.shape[1] != 2:
        raise ValueError(f"path must have shape (k,2), got {path.shape}")
    if path.min() < 0 or (path[:, 0] >= ny).any() or (path[:, 1] >= nx).any():
        raise ValueError(f"path leaves the ({ny}, {nx}) grid")
    flat = path[:, 0] * nx + path[:, 1]
    if len(flat) != ny * nx or len(np.unique(flat)) != ny * nx:
        raise ValueError(f"path must visit each of the {ny * nx} grid points exactly once, got {len(flat)} steps")
    step = np.abs(np.diff(path, axis=0)).sum(axis=1)
    if (step != 1).any():
        k = int(np.flatnonzero(step != 1)[0])
        raise ValueError(
            f"path step {k} jumps from {tuple(path[k])} to {tuple(path[k + 1])}; steps must join 4-neighbours"
        )


def _as_field(D):
    D = np.asarray(D, dtype=float)
    if D.ndim == 2:
        D = D[..., None]
    if D.ndim != 3:
        raise ValueError(f"trajectory must have shape (ny, nx) or (ny, nx, c), got {D.shape}")
    return D


def plane_fit_residual(grid, D):
    """Relative residual of the best affine fit a + b q^x + c q^y to a trajectory.

    Parameters
    ----------
    grid : HandleGrid
    D : (ny, nx) or (ny, nx, c) numpy array
        Trajectory components (e.g. ``traj.of(v)``).

    Returns
    -------
    float
        max |residual| / max |D - mean(D)| over all components (0 for a constant field).
        A DefOp with the linear handle basis gives ~1e-15.
    """
    D = _as_field(D)
    if D.shape[:2] != grid.shape:
        raise ValueError(f"trajectory shape {D.shape[:2]} does not match grid shape {grid.shape}")
    d = grid.displacements.reshape(-1, 2)
    A = np.column_stack([np.ones(len(d)), d])
    Z = D.reshape(len(d), -1)
    coef, *_ = np.linalg.lstsq(A, Z, rcond=None)
    res = np.abs(Z - A @ coef).max()
    scale = np.abs(Z - Z.mean(axis=0)).max()
    return float(res / scale) if scale > 0 else float(res)


def neighbour_jumps(D):
    """Jumps between 4-neighbouring grid points.

    Parameters
    ----------
    D : (ny, nx) or (ny, nx, c) numpy array

    Returns
    -------
    jx : (ny, nx-1) numpy array
        |D[i, j+1] - D[i, j]| (Euclidean over components).
    jy : (ny-1, nx) numpy array
        |D[i+1, j] - D[i, j]|.
    """
    D = _as_field(D)
    jx = np.linalg.norm(np.diff(D, axis=1), axis=-1)
    jy = np.linalg.norm(np.diff(D, axis=0), axis=-1)
    return jx, jy


def max_jump(grid, D):
    """Largest neighbour jump divided by the grid step: a discrete Lipschitz constant.

    For a smooth trajectory this is about the largest slope |∂T/∂q| and stays put when the grid is
    refined; across a discontinuity it grows like 1/h.
    """
    jx, jy = neighbour_jumps(D)
    hx, hy = grid.spacing
    vals = []
    if jx.size:
        vals.append(jx.max() / hx)
    if jy.size:
        vals.append(jy.max() / hy)
    return float(max(vals))


def jump_ratio(D):
    """Largest neighbour jump / median neighbour jump (scale free).

    A smooth trajectory sampled on a grid has ratio of a few; a jump of the minimiser (a
    discontinuity of the variational DefOp) gives a large ratio.
    """
    jx, jy = neighbour_jumps(D)
    j = np.concatenate([jx.ravel(), jy.ravel()])
    med = np.median(j)
    if med <= 0:
        return float("inf") if j.max() > 0 else 1.0
    return float(j.max() / med)


def discontinuities(D, factor=8.0):
    """Grid edges across which the trajectory jumps: jump > ``factor`` x median jump.

    Parameters
    ----------
    D : (ny, nx) or (ny, nx, c) numpy array
    factor : float
        Threshold relative to the median neighbour jump.

    Returns
    -------
    ex : (ny, nx-1) numpy bool array
        True where the edge between [i, j] and [i, j+1] crosses a discontinuity.
    ey : (ny-1, nx) numpy bool array
        True where the edge between [i, j] and [i+1, j] crosses a discontinuity.
    """
    if factor <= 1:
        raise ValueError(f"factor must be > 1, got {factor}")
    jx, jy = neighbour_jumps(D)
    med = np.median(np.concatenate([jx.ravel(), jy.ravel()]))
    return jx > factor * med, jy > factor * med


def discontinuity_points(grid, D, factor=8.0):
    """Handle displacements (k, 2) at the midpoints of the edges returned by ``discontinuities``."""
    ex, ey = discontinuities(D, factor)
    d = grid.displacements
    mx = 0.5 * (d[:, 1:] + d[:, :-1])[ex]
    my = 0.5 * (d[1:, :] + d[:-1, :])[ey]
    return np.concatenate([mx, my], axis=0).reshape(-1, 2)


def path_jumps(D, path):
    """(k-1,) jumps |D[path[s+1]] - D[path[s]]| along a visiting order (e.g. the warm-start path)."""
    D = _as_field(D)
    path = np.asarray(path, dtype=np.int64)
    check_path(path, D.shape[:2])
    vals = D[path[:, 0], path[:, 1]]
    return np.linalg.norm(np.diff(vals, axis=0), axis=-1)


def range_and_error(T, reference="ground truth", mask=None):
    """Range of each trajectory and its largest error against a reference trajectory (Figs. 3, 5).

    An approximation that *overshoots* reaches displacements the reference never reaches: it leaves
    the reference's range, typically next to a jump of the reference.

    Parameters
    ----------
    T : dict of str -> (ny, nx, 2) numpy array
        Trajectories T_x of one point on one grid (e.g. ``{name: traj.of(x)}``), ``reference`` among them.
    reference : str
        Key of the ground truth.
    mask : (ny, nx) numpy bool array, optional
        Grid points to measure (default: all), e.g. leaving out points where the reference is ambiguous.

    Returns
    -------
    dict of str -> dict
        Per trajectory, over the measured grid points: ``low``, ``high`` (2,) numpy arrays, the smallest
        and largest value of each component (x, y); ``extent`` (2,) numpy array, max |T_x| per component
        (the "±" range); ``overshoot`` (2,) numpy array, how far each component leaves the reference's
        [low, high] (0 when it stays inside); ``max_error`` float, the largest Euclidean error
        |T_x − T_ref|; ``argmax`` (i, j), the grid index where that error is largest.

    Raises
    ------
    ValueError
        A missing reference, a bad mask, trajectories of different shapes, or NaN/inf at a measured grid point.
    """
    if reference not in T:
        raise ValueError(f"reference {reference!r} is not among the trajectories {sorted(T)}")
    ref = np.asarray(T[reference], dtype=float)
    if ref.ndim != 3 or ref.shape[-1] != 2:
        raise ValueError(f"trajectories must have shape (ny, nx, 2), got {ref.shape} for {reference!r}")
    mask = np.ones(ref.shape[:2], dtype=bool) if mask is None else np.asarray(mask)
    if mask.shape != ref.shape[:2] or mask.dtype != bool or not mask.any():
        raise ValueError(f"mask must be a boolean {ref.shape[:2]} array with at least one True, got {mask.shape}")
    lo_ref, hi_ref = ref[mask].min(axis=0), ref[mask].max(axis=0)
    out = {}
    for name, t in T.items():
        t = np.asarray(t, dtype=float)
        if t.shape != ref.shape:
            raise ValueError(f"trajectory {name!r} has shape {t.shape}, the reference {ref.shape}")
        if not np.isfinite(t[mask]).all():
            raise ValueError(f"trajectory {name!r} has NaN or infinite values at measured grid points")
        err = np.where(mask, np.linalg.norm(t - ref, axis=-1), -np.inf)
        lo, hi = t[mask].min(axis=0), t[mask].max(axis=0)
        out[name] = {
            "low": lo,
            "high": hi,
            "extent": np.abs(t[mask]).max(axis=0),
            "overshoot": np.maximum(0.0, np.maximum(lo_ref - lo, hi - hi_ref)),
            "max_error": float(err.max()),
            "argmax": tuple(int(i) for i in np.unravel_index(np.argmax(err), err.shape)),
        }
    return out
