"""Polygons of a surface file as triangles: fans for convex ones, ear clipping for the other simple planar ones.

A polygon of k > 3 vertices is projected onto its plane (Newell's normal, the area vector of the polygon,
through its centroid). It is refused, naming the face, when a vertex lies farther than
:data:`PLANARITY_TOLERANCE` × its diameter from that plane, when its area is zero, when it repeats a vertex,
or when two of its edges cross or touch (not a simple polygon). A strictly convex polygon becomes the fan from
its first vertex (the triangles every reader made before); any other simple polygon is triangulated by ear
clipping (``mapbox_earcut``, ISC licence: its triangles cover the polygon exactly, none outside it). Every
triangle keeps the polygon's orientation.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PLANARITY_TOLERANCE", "triangulate"]

#: the farthest a vertex of a polygon may lie from the polygon's plane, × the polygon's diameter
PLANARITY_TOLERANCE = 1e-3


def triangulate(V, polygons, where):
    """The triangles (k, 3) of polygons (sequences of vertex indices into V), in their order.

    Parameters
    ----------
    V : (n, 3) numpy array
    polygons : list of sequences of int, or (m, k) int numpy array
    where : callable
        ``where(i)`` names polygon i in a message, for example ``"OBJ line 12: the face"``.

    Raises
    ------
    ValueError
        A polygon with fewer than 3 vertices, an index outside V, or a polygon (k > 3) that is not planar, has no
        area, repeats a vertex or crosses itself; the message names it with ``where``.
    """
    if isinstance(polygons, np.ndarray):  # (m, k): polygons of one size
        sizes = np.full(len(polygons), polygons.shape[1] if polygons.ndim == 2 else 0, dtype=np.int64)
    else:
        sizes = np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))
    small = np.flatnonzero(sizes < 3)
    if len(small):
        raise ValueError(f"{where(int(small[0]))} has {sizes[small[0]]} vertices, a face needs at least 3")
    start = np.concatenate([[0], np.cumsum(sizes - 2)])
    F = np.empty((int(start[-1]), 3), dtype=np.int64)
    for k in np.unique(sizes).tolist():
        rows = np.flatnonzero(sizes == k)
        if isinstance(polygons, np.ndarray):
            P = np.asarray(polygons, dtype=np.int64)
        else:
            P = np.array([polygons[i] for i in rows.tolist()], dtype=np.int64).reshape(len(rows), k)
        out = (P < 0) | (P >= len(V))
        if out.any():
            r, j = (int(x) for x in np.argwhere(out)[0])
            raise ValueError(f"{where(int(rows[r]))} indexes vertex {int(P[r, j])}, but the file has {len(V)} vertices")
        tris = _fans(P) if k == 3 else _polygons(np.asarray(V, dtype=np.float64), P, rows, where)
        F[(start[rows][:, None] + np.arange(k - 2)).ravel()] = tris.reshape(-1, 3)
    return F


def _fans(P):
    """(m, k-2, 3): the fan of each row of P from its first vertex."""
    k = P.shape[1]
    j = np.arange(1, k - 1)
    return np.stack([np.repeat(P[:, :1], k - 2, axis=1), P[:, j], P[:, j + 1]], axis=2)


def _polygons(V, P, rows, where):
    """(m, k-2, 3) triangles of the m polygons P (m, k), k > 3, after the planarity and area checks."""
    m, k = P.shape
    S = np.sort(P, axis=1)
    rep = np.flatnonzero((S[:, 1:] == S[:, :-1]).any(axis=1))
    if len(rep):
        raise ValueError(f"{where(int(rows[rep[0]]))} repeats a vertex (not a simple polygon)")
    X = V[P]
    X = X - X.mean(axis=1, keepdims=True)
    N = 0.5 * np.cross(X, np.roll(X, -1, axis=1)).sum(axis=1)  # Newell: the area vector
    diam = np.linalg.norm(np.ptp(X, axis=1), axis=1)
    area = np.linalg.norm(N, axis=1)
    flat = np.flatnonzero(~(area > 1e-12 * diam**2))
    if len(flat):
        raise ValueError(f"{where(int(rows[flat[0]]))} has zero area (its {k} vertices lie on a line or fold onto it)")
    n = N / area[:, None]
    off = np.abs(np.einsum("mkd,md->mk", X, n)).max(axis=1) / diam
    bent = np.flatnonzero(off > PLANARITY_TOLERANCE)
    if len(bent):
        b = int(bent[0])
        raise ValueError(
            f"{where(int(rows[b]))} is not planar: a vertex lies {off[b]:.2g} × its diameter from its plane "
            f"(tolerance {PLANARITY_TOLERANCE:g}, defop.geometry.surface_files.PLANARITY_TOLERANCE); split it into "
            "triangles in the file"
        )
    E = np.roll(X, -1, axis=1) - X
    Eprev = np.roll(E, 1, axis=1)
    turn = np.einsum("mkd,md->mk", np.cross(Eprev, E), n)
    winding = np.arctan2(turn, np.einsum("mkd,mkd->mk", Eprev, E)).sum(axis=1)
    convex = (turn > 1e-12 * diam[:, None] ** 2).all(axis=1) & (np.abs(winding - 2 * np.pi) < 1e-6)
    tris = _fans(P)
    for r in np.flatnonzero(~convex).tolist():
        tris[r] = P[r][_ear_clip(X[r], n[r], lambda r=r: where(int(rows[r])))]
    return tris


def _ear_clip(X, n, where):
    """(k-2, 3) local indices triangulating the planar polygon X (k, 3) with unit normal n, oriented along n."""
    import mapbox_earcut

    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    Y = np.column_stack([X @ u, X @ np.cross(n, u)])  # counter-clockwise seen from n
    k = len(Y)
    _check_simple(Y, where)
    T = np.asarray(mapbox_earcut.triangulate_float64(Y, np.array([k], dtype=np.uint32)), dtype=np.int64)
    T = T.reshape(-1, 3)
    a, b, c = Y[T[:, 0]], Y[T[:, 1]], Y[T[:, 2]]
    signed = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    total = 0.5 * np.dot(Y[:, 0], np.roll(Y[:, 1], -1)) - 0.5 * np.dot(np.roll(Y[:, 0], -1), Y[:, 1])
    if len(T) != k - 2 or not np.isclose(0.5 * np.abs(signed).sum(), total, rtol=1e-9, atol=0):
        raise ValueError(f"{where()} could not be triangulated (ear clipping covered it with {len(T)} triangles)")
    T[signed < 0] = T[signed < 0][:, [0, 2, 1]]
    return T


def _check_simple(Y, where):
    """ValueError unless no two edges of the closed polygon Y (k, 2) meet other than adjacent ones at their corner."""
    k = len(Y)
    A, B = Y, np.roll(Y, -1, axis=0)
    for i in range(k - 2):
        j = np.arange(i + 2, k if i > 0 else k - 1)  # edges not adjacent to edge i
        if not len(j):
            continue
        if _segments_meet(A[i], B[i], A[j], B[j]).any():
            jj = int(j[_segments_meet(A[i], B[i], A[j], B[j])][0])
            raise ValueError(f"{where()} crosses itself: its edges {i} and {jj} meet (not a simple polygon)")


def _segments_meet(p, q, A, B):
    """Whether segment pq meets each segment A[i]B[i] (touching counts)."""

    def orient(a, b, c):
        return np.sign(
            (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
        )

    d1, d2 = orient(A, B, p), orient(A, B, q)
    d3, d4 = orient(p, q, A), orient(p, q, B)
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)

    def on(a, b, c):  # c on segment ab, given collinear
        return (
            (np.minimum(a[..., 0], b[..., 0]) <= c[..., 0])
            & (c[..., 0] <= np.maximum(a[..., 0], b[..., 0]))
            & (np.minimum(a[..., 1], b[..., 1]) <= c[..., 1])
            & (c[..., 1] <= np.maximum(a[..., 1], b[..., 1]))
        )

    touch = (
        ((d1 == 0) & on(A, B, p)) | ((d2 == 0) & on(A, B, q)) | ((d3 == 0) & on(p, q, A)) | ((d4 == 0) & on(p, q, B))
    )
    return proper | touch
