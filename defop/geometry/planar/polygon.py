"""Polygon geometry and the checks that guard Triangle.

Everything here is element-wise numpy arithmetic (and ``np.sum``/``np.min`` reductions), never a
BLAS call (``@``, ``np.dot``, ``np.einsum``, a vector ``np.linalg.norm``): OpenBLAS picks its kernels
per CPU, and a rounding difference of 3e-16 in an outline becomes a different Triangle mesh.
:func:`validate_polygon` rejects what Triangle cannot mesh (it segfaults on a pinched
polygon, a zero-width spike or a hole identical to the outline) with a ``ValueError`` that names the
offending vertex, edge or hole. Tolerances are relative to the outline's size, so a
1e-12-sized square is as valid as a unit one.
"""

from __future__ import annotations

import numpy as np

#: relative tolerance (× bounding-box diagonal) under which a vertex "touches" an edge
TOUCH_TOL = 1e-10


def loop_names(n_holes):
    """Names used in messages: ``["outer polygon", "hole 0", ...]``."""
    return ["outer polygon"] + [f"hole {k}" for k in range(n_holes)]


def polygon_area(poly):
    """Signed area of a closed polygon (shoelace; > 0 when counter-clockwise).

    Parameters
    ----------
    poly : (k,2) numpy array

    Returns
    -------
    area : float
    """
    P = np.asarray(poly, float)
    P = P - P[0]  # about the first vertex: far from the origin the products would cancel (a square at 1e8)
    x, y = P[:, 0], P[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def diagonal(P):
    """Bounding-box diagonal of points ``P (k,2)`` (element-wise, no BLAS)."""
    ext = np.ptp(np.asarray(P, float), axis=0)
    return float(np.sqrt(ext[0] * ext[0] + ext[1] * ext[1]))


def check_polygon(poly, name="polygon"):
    """A polygon as a (k,2) float array without a repeated closing point.

    Parameters
    ----------
    poly : (k,2) array-like
    name : str
        Used in messages ("outer polygon", "hole 2").

    Returns
    -------
    P : (k,2) numpy array

    Raises
    ------
    ValueError
        Wrong shape, NaN/inf, fewer than 3 points, or a point repeated consecutively.
    """
    try:
        P = np.asarray(poly, dtype=float)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an array of (x, y) points: {e}") from None
    if P.ndim != 2 or P.shape[1] != 2:
        raise ValueError(f"{name} must have shape (k,2), got {P.shape}")
    if not np.isfinite(P).all():
        first = int(np.argwhere(~np.isfinite(P))[0, 0])
        raise ValueError(f"{name} has NaN or infinite coordinates (first at point {first})")
    if len(P) > 1 and np.array_equal(P[0], P[-1]):
        P = P[:-1]  # closed explicitly
    if len(P) < 3:
        raise ValueError(f"{name} has {len(P)} points; a polygon needs at least 3")
    same = np.all(np.roll(P, -1, axis=0) == P, axis=1)
    if same.any():
        i = int(np.flatnonzero(same)[0])
        raise ValueError(f"{name} repeats point {i} at ({P[i, 0]:.6g}, {P[i, 1]:.6g}) as point {(i + 1) % len(P)}")
    return P


def _orient(p, q, r):
    return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])


def _edges(loops):
    """All edges of all loops: starts (e,2), ends (e,2), loop id (e,), index in its loop (e,)."""
    A = np.vstack(loops)
    B = np.vstack([np.roll(L, -1, axis=0) for L in loops])
    loop = np.concatenate([np.full(len(L), a) for a, L in enumerate(loops)])
    idx = np.concatenate([np.arange(len(L)) for L in loops])
    return A, B, loop, idx


def self_intersections(loops):
    """Pairs of crossing edges among closed polygons (edges i of loop a and j of loop b).

    Candidate pairs come from a k-d tree on the edge midpoints, so this is about linear in the
    number of edges for outlines with edges of similar length.

    Parameters
    ----------
    loops : list of (k,2) numpy array

    Returns
    -------
    crossings : list of ((int, int), (int, int))
        ``((loop_a, edge_i), (loop_b, edge_j))``, sorted, empty when no two edges cross properly.
    """
    from scipy.spatial import cKDTree

    A, B, loop, idx = _edges(loops)
    mid = 0.5 * (A + B)
    d = B - A
    half = 0.5 * np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)
    pairs = cKDTree(mid).query_pairs(2 * half.max() * (1 + 1e-9), output_type="ndarray")
    if not len(pairs):
        return []
    p, q = pairs[:, 0], pairs[:, 1]
    d1, d2 = _orient(A[p], B[p], A[q]), _orient(A[p], B[p], B[q])
    d3, d4 = _orient(A[q], B[q], A[p]), _orient(A[q], B[q], B[p])
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    out = set()
    for e, f in zip(p[hit], q[hit]):
        x, y = (int(loop[e]), int(idx[e])), (int(loop[f]), int(idx[f]))
        out.add((min(x, y), max(x, y)))
    return sorted(out)


def _point_segment_distance(pts, A, B):
    """(k,) distances from points pts[k] to segments A[k]B[k], element-wise."""
    dx, dy = B[:, 0] - A[:, 0], B[:, 1] - A[:, 1]
    px, py = pts[:, 0] - A[:, 0], pts[:, 1] - A[:, 1]
    dd = dx * dx + dy * dy
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dd > 0, (px * dx + py * dy) / dd, 0.0)
    t = np.clip(t, 0.0, 1.0)
    ex, ey = px - t * dx, py - t * dy
    return np.sqrt(ex * ex + ey * ey)


def touching_vertices(loops, tol):
    """Vertices that lie within ``tol`` of an edge they are not an end of.

    Parameters
    ----------
    loops : list of (k,2) numpy array
    tol : float

    Returns
    -------
    touches : list of ((int, int), (int, int), float)
        ``((loop_a, vertex_i), (loop_b, edge_j), distance)``, sorted.
    """
    from scipy.spatial import cKDTree

    A, B, loop, idx = _edges(loops)  # vertex k of the stack is the start of edge k
    d = B - A
    half = 0.5 * np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2)
    near = cKDTree(A).query_ball_point(0.5 * (A + B), half * (1 + 1e-9) + tol)
    e = np.repeat(np.arange(len(A)), [len(n) for n in near])
    if not len(e):
        return []
    v = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
    n_loop = np.array([len(L) for L in loops])[loop[e]]
    own = (loop[v] == loop[e]) & ((idx[v] == idx[e]) | (idx[v] == (idx[e] + 1) % n_loop))
    v, e = v[~own], e[~own]
    dist = _point_segment_distance(A[v], A[e], B[e])
    hit = dist <= tol
    out = [
        ((int(loop[a]), int(idx[a])), (int(loop[b]), int(idx[b])), float(t))
        for a, b, t in zip(v[hit], e[hit], dist[hit])
    ]
    return sorted(out)


def distance_to_outline(points, loops):
    """Distance of each point to the nearest outline edge.

    Parameters
    ----------
    points : (k,2) numpy array
    loops : list of (l,2) numpy array

    Returns
    -------
    dist : (k,) numpy array
    """
    pts = np.atleast_2d(np.asarray(points, float))
    A, B, _, _ = _edges(loops)
    best = np.full(len(pts), np.inf)
    for start in range(0, len(pts), 64):
        P = pts[start : start + 64]
        k, m = len(P), len(A)
        D = _point_segment_distance(np.repeat(P, m, axis=0), np.tile(A, (k, 1)), np.tile(B, (k, 1)))
        best[start : start + k] = D.reshape(k, m).min(axis=1)
    return best


def spikes(P, tol):
    """Vertices of a loop where it turns back on itself (a zero-width spike).

    Parameters
    ----------
    P : (k,2) numpy array
    tol : float
        Relative tolerance on the sine of the turning angle.

    Returns
    -------
    idx : (s,) int numpy array
    """
    e_in = P - np.roll(P, 1, axis=0)
    e_out = np.roll(P, -1, axis=0) - P
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    dot = e_in[:, 0] * e_out[:, 0] + e_in[:, 1] * e_out[:, 1]
    lens = np.sqrt((e_in[:, 0] ** 2 + e_in[:, 1] ** 2) * (e_out[:, 0] ** 2 + e_out[:, 1] ** 2))
    return np.flatnonzero((np.abs(cross) <= tol * lens) & (dot < 0))


#: extents a polygon may have: beyond them squared lengths and areas underflow or overflow a float
SCALE_RANGE = (1e-60, 1e60)  # fourth powers (products of squared lengths) stay normal floats


def _check_crossings(loops, what, scale):
    """ValueError for two edges that cross or a vertex that touches an edge (a pinch), naming both."""
    crossings = self_intersections(loops)
    if crossings:
        (a, i), (b, j) = crossings[0]
        raise ValueError(
            f"the polygon is self-intersecting: edge {i} of the {what[a]} crosses edge {j} of the {what[b]} "
            f"({len(crossings)} crossing(s) in all)"
        )
    touches = touching_vertices(loops, TOUCH_TOL * scale)
    if touches:
        (a, i), (b, j), d = touches[0]
        v = loops[a][i]
        where = "the same polygon" if a == b else f"the {what[b]}"
        raise ValueError(
            f"vertex {i} of the {what[a]} at ({v[0]:.6g}, {v[1]:.6g}) touches edge {j} of {where} "
            f"(distance {d:.3g}); a pinched polygon cannot be meshed"
        )


def validate_polygon(outer, holes=()):
    """Check that an outline with holes is something Triangle can mesh.

    The outer polygon and every hole must be simple (no crossing edges, no vertex touching a
    non-adjacent edge, no zero-width spike, non-zero area); every hole must lie strictly inside the
    outer polygon, and holes must be disjoint and not nested (a hole inside a hole, an island, is
    rejected: mesh the island as a shape of its own).

    Parameters
    ----------
    outer : (k,2) array-like
    holes : list of (l,2) array-like

    Returns
    -------
    outer : (k,2) numpy array
    holes : list of (l,2) numpy array
        Without repeated closing points.

    Raises
    ------
    ValueError
        Naming the offending vertex, edge or hole; or the extent, when it is outside :data:`SCALE_RANGE`.
    """
    if isinstance(holes, np.ndarray) and holes.ndim == 2:
        holes = [holes]  # a single hole given as an array
    outer = check_polygon(outer, "outer polygon")
    holes = [check_polygon(H, f"hole {i}") for i, H in enumerate(holes)]
    loops = [outer, *holes]
    what = loop_names(len(holes))
    ext = np.ptp(np.vstack(loops), axis=0).max()
    if not SCALE_RANGE[0] <= ext <= SCALE_RANGE[1]:
        raise ValueError(
            f"the polygon's extent {ext:.3g} is outside the supported range [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}] "
            "(its areas and squared lengths would underflow or overflow); rescale the coordinates"
        )
    scale = diagonal(np.vstack(loops))
    for i, H in enumerate(holes):
        if len(H) == len(outer) and np.array_equal(np.unique(H, axis=0), np.unique(outer, axis=0)):
            raise ValueError(f"hole {i} is identical to the outer polygon")
    for L, w in zip(loops, what):
        s = spikes(L, 1e-12)
        if len(s):
            v = L[s[0]]
            raise ValueError(f"the {w} has a zero-width spike at vertex {int(s[0])} ({v[0]:.6g}, {v[1]:.6g})")
    _check_crossings(loops, what, scale)
    for L, w in zip(loops, what):
        if abs(polygon_area(L)) <= 1e-14 * diagonal(L) ** 2:
            raise ValueError(f"the {w} has zero area")
    _check_holes_placement(outer, holes)
    return outer, holes


def _check_holes_placement(outer, holes):
    """Holes inside the outer polygon, not inside each other (the loops are already disjoint)."""
    for i, H in enumerate(holes):
        if not points_in_polygon(H[:1], [outer])[0]:
            raise ValueError(
                f"hole {i} is outside the outer polygon (its vertex 0 at ({H[0, 0]:.6g}, {H[0, 1]:.6g}) is not "
                "inside it)"
            )
    for i, H in enumerate(holes):
        for j, G in enumerate(holes):
            if i != j and points_in_polygon(H[:1], [G])[0]:
                raise ValueError(
                    f"hole {i} lies inside hole {j}: nested holes (an island in a hole) are not supported; "
                    "mesh the island as a shape of its own"
                )


def points_in_polygon(points, loops):
    """Even-odd point-in-polygon test against an outline with holes.

    Parameters
    ----------
    points : (k,2) numpy array
    loops : list of (l,2) numpy array
        The outer loop and the holes.

    Returns
    -------
    inside : (k,) bool numpy array
    """
    pts = np.atleast_2d(np.asarray(points, float))
    inside = np.zeros(len(pts), bool)
    for P in loops:
        Q = np.roll(P, -1, axis=0)
        x, y = pts[:, 0:1], pts[:, 1:2]
        cond = (P[None, :, 1] > y) != (Q[None, :, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = P[None, :, 0] + (y - P[None, :, 1]) * (Q[None, :, 0] - P[None, :, 0]) / (Q[None, :, 1] - P[None, :, 1])
        inside ^= (np.sum(cond & (x < xc), axis=1) % 2).astype(bool)
    return inside


def interior_point(loop):
    """A (2,) point strictly inside the simple polygon ``loop``, a (k,2) array: its centroid if inside, else a
    probe near a vertex."""
    c = loop.mean(axis=0)
    if points_in_polygon(c[None], [loop])[0]:
        return c
    for k in range(2, len(loop)):  # midpoints between the first vertex and every other vertex
        m = 0.5 * (loop[0] + loop[k])
        if points_in_polygon(m[None], [loop])[0]:
            return m
    raise ValueError("could not find a point inside a hole")


def _arclength(P):
    d = np.diff(P, axis=0)
    return np.concatenate([[0.0], np.cumsum(np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2))])


def insert_on_outline(loops, points):
    """The loops with each point inserted as a vertex on its nearest edge (in order along the edge; a point at an
    edge's end replaces that vertex), its coordinates exactly: points on the outline become outline vertices.

    Parameters
    ----------
    loops : list of (l,2) numpy array
    points : (k,2) numpy array
        Points on (or within round-off of) the outline, distinct.

    Returns
    -------
    list of (l',2) numpy array
    """
    pts = np.atleast_2d(np.asarray(points, float)).reshape(-1, 2)
    A, B, loop, idx = _edges(loops)
    out = [np.asarray(L, float).copy() for L in loops]
    extra = [[[] for _ in L] for L in loops]  # per loop, per edge: (t, point)
    for p in pts:
        e = int(np.argmin(_point_segment_distance(np.repeat(p[None], len(A), axis=0), A, B)))
        d = B[e] - A[e]
        t = float(np.clip(np.dot(p - A[e], d) / max(np.dot(d, d), 1e-300), 0.0, 1.0))
        a, i = int(loop[e]), int(idx[e])
        if t <= 1e-9:
            out[a][i] = p
        elif t >= 1 - 1e-9:
            out[a][(i + 1) % len(out[a])] = p
        else:
            extra[a][i].append((t, p))
    return [
        np.array([v for i, x in enumerate(L) for v in [x, *(q for _, q in sorted(ex[i], key=lambda c: c[0]))]])
        for L, ex in zip(out, extra)
    ]


def resample(loop, h, corner_angle=20.0, keep=None):
    """Resample a closed polyline by arc length with spacing about ``h``, keeping its corners.

    Vertices where the outline turns by more than ``corner_angle`` degrees are kept exactly
    (so a polygon's area is preserved), and those equal to a point of ``keep``; the pieces between them are
    resampled uniformly.

    Parameters
    ----------
    loop : (k,2) numpy array
    h : float
    corner_angle : float
    keep : (j,2) numpy array, optional
        Points to keep where they are vertices of the loop (:func:`insert_on_outline`).

    Returns
    -------
    out : (l,2) numpy array, l >= 8 unless the loop has fewer corners than that
    """
    P = np.asarray(loop, float)
    e_in = P - np.roll(P, 1, axis=0)
    e_out = np.roll(P, -1, axis=0) - P
    dot = e_in[:, 0] * e_out[:, 0] + e_in[:, 1] * e_out[:, 1]
    cosang = dot / np.sqrt((e_in[:, 0] ** 2 + e_in[:, 1] ** 2) * (e_out[:, 0] ** 2 + e_out[:, 1] ** 2))
    sharp = cosang < np.cos(np.radians(corner_angle))
    if keep is not None and len(keep):
        sharp |= (P[:, None, :] == np.asarray(keep, float)[None]).all(axis=2).any(axis=1)
    corners = np.flatnonzero(sharp)
    if len(corners) == 0:
        Pc = np.vstack([P, P[:1]])
        s = _arclength(Pc)
        n = max(8, int(round(s[-1] / h)))
        t = np.linspace(0, s[-1], n, endpoint=False)
        return np.column_stack([np.interp(t, s, Pc[:, 0]), np.interp(t, s, Pc[:, 1])])
    out = []
    for a, b in zip(corners, np.roll(corners, -1)):
        idx = np.arange(a, b + 1) if b > a else np.concatenate([np.arange(a, len(P)), np.arange(0, b + 1)])
        piece = P[idx]
        s = _arclength(piece)
        n = max(1, int(round(s[-1] / h)))
        t = np.linspace(0, s[-1], n, endpoint=False)
        out.append(np.column_stack([np.interp(t, s, piece[:, 0]), np.interp(t, s, piece[:, 1])]))
    return np.vstack(out)
