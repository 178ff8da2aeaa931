"""Handles of a shape: their vertex indices, the vertex nearest each handle point, and the 3D span check."""

from __future__ import annotations

import numpy as np

from .. import options as opt

__all__ = ["check_handles_span", "handle_vertices", "handle_indices"]


def check_handles_span(P):
    """Raise ValueError if the handle points P (h,3) lie on one line (or are fewer than 3).

    Point handles fix positions only: a rotation about a line through all of them costs nothing, so
    the variational problem has no unique minimum (its Hessian is singular).
    """
    P = np.asarray(P, float)
    if len(P) >= 3:
        D = P - P[0]
        len2 = D[:, 0] * D[:, 0] + D[:, 1] * D[:, 1] + D[:, 2] * D[:, 2]
        u = D[int(np.argmax(len2))]
        C = np.column_stack(
            [D[:, 1] * u[2] - D[:, 2] * u[1], D[:, 2] * u[0] - D[:, 0] * u[2], D[:, 0] * u[1] - D[:, 1] * u[0]]
        )
        off = np.sqrt((C[:, 0] * C[:, 0] + C[:, 1] * C[:, 1] + C[:, 2] * C[:, 2]) / max(float(len2.max()), 1e-300))
        if off.max() > 1e-9 * np.sqrt(max(float(len2.max()), 1e-300)):
            return
    what = f"the {len(P)} handles lie on one line" if len(P) > 1 else "a single handle"
    raise ValueError(
        f"{what}: in 3D a rotation about a line through them costs nothing (the Hessian is singular); "
        "use at least 3 handles that are not collinear (for example a small patch of handles)"
    )


def handle_vertices(mesh, points, tolerance=0.5):
    """The mesh vertex of each handle point (the nearest one); ValueError for points outside the mesh.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    points : (h,d) numpy array
    tolerance : float
        A point outside the mesh is accepted if its nearest vertex is at most ``tolerance`` × the typical
        edge length away (the snapped boundary of a tetrahedral mesh may pass just inside a surface point).

    Returns
    -------
    idx : (h,) int64 numpy array
    """
    H = opt.real_array("handles", points)
    if H.ndim != 2 or H.shape[1] != mesh.dim or len(H) == 0:
        raise ValueError(f"handles must have shape (h,{mesh.dim}), got {np.shape(points)}")
    if not np.isfinite(H).all():
        raise ValueError("handles have NaN or infinite entries")
    idx, dist = mesh.nearest_vertex(H)
    edge = (6 * float(np.median(mesh.volumes))) ** (1 / 3) if mesh.dim == 3 else np.sqrt(2 * np.median(mesh.volumes))
    outside = ~mesh.contains(H) & (dist > tolerance * edge)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise ValueError(f"handle {k} is outside the mesh (nearest vertex is {dist[k]:.3g} away)")
    uniq, first, counts = np.unique(idx, return_index=True, return_counts=True)
    if (counts > 1).any():
        v = int(uniq[counts > 1][0])
        a, b = np.flatnonzero(idx == v)[:2]
        raise ValueError(
            f"handles {a} and {b} both become vertex {v} (the nearest to each): move them apart or use more vertices"
        )
    return idx


def handle_indices(handles, n):
    """Handle vertex indices as an int64 array: integers (or integral floats), or a boolean mask.

    Parameters
    ----------
    handles : (h,) int array-like or (n,) bool array-like
    n : int
        Number of mesh vertices.

    Returns
    -------
    idx : (h,) int64 numpy array

    Raises
    ------
    ValueError
        A non-integral index (1.7 is not truncated to 1), a mask of the wrong length, or another dtype.
    """
    h = np.asarray(handles)
    if h.dtype == bool:
        if h.shape != (n,):
            raise ValueError(f"a boolean handle mask needs one entry per vertex ({n}), got shape {h.shape}")
        return np.flatnonzero(h).astype(np.int64)
    h = h.ravel()
    if np.issubdtype(h.dtype, np.floating):
        bad = ~np.isfinite(h) | (h != np.round(h))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"handle {k} is {h[k].item()!r}, not an integer vertex index")
    elif not np.issubdtype(h.dtype, np.integer):
        raise ValueError(f"handles must be integer vertex indices or a boolean mask, got dtype {h.dtype}")
    return h.astype(np.int64)
