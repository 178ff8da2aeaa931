"""Polygons with holes → quality triangle meshes by Shewchuk's Triangle.

The outline is validated first (:func:`defop.geometry.planar.polygon.validate_polygon`): Triangle segfaults on a
pinched polygon, a zero-width spike or a hole identical to the outline. Every step before Triangle is
element-wise arithmetic, so the mesh is the same on every CPU and BLAS build.
"""

from __future__ import annotations

import math

import numpy as np

from ... import options as opt
from ..mesh import Mesh
from .polygon import (
    diagonal,
    distance_to_outline,
    insert_on_outline,
    interior_point,
    points_in_polygon,
    polygon_area,
    resample,
    validate_polygon,
)

#: most vertices a mesh may be asked for (Triangle takes about 3 s per million here)
MAX_VERTICES = 1_000_000


def _triangle(outer, holes, points, max_area):
    """Triangle on loops (and Steiner points), with the lonely-ear vertices split off."""
    import triangle as tr

    loops = [outer, *holes]
    verts = np.vstack(loops + ([points] if len(points) else []))
    segs, start = [], 0
    for L in loops:
        k = len(L)
        segs.append(np.column_stack([np.arange(k), (np.arange(k) + 1) % k]) + start)
        start += k
    data = {"vertices": verts, "segments": np.vstack(segs)}
    if holes:
        data["holes"] = np.array([interior_point(H) for H in holes])
    flags = "pqQj" + (_area_flag(max_area) if max_area else "")
    out = _run(tr, data, flags)
    # a vertex in a single triangle (an "ear" at a sharp corner) is badly constrained by FEM energies:
    # split such triangles at their centroid
    for _ in range(3):
        V, F = out["vertices"], out["triangles"]
        lone = np.flatnonzero(np.bincount(F.ravel(), minlength=len(V)) == 1)
        if not len(lone):
            break
        ears = F[np.isin(F, lone).any(axis=1)]
        data["vertices"] = np.vstack([data["vertices"], V[ears].mean(axis=1)])
        out = _run(tr, data, flags)
    return out["vertices"], out["triangles"]


def _area_flag(max_area):
    """Triangle's area flag in plain decimals (it misreads exponents), at least 6 significant digits."""
    digits = max(10, 6 - math.floor(math.log10(max_area)))
    return f"a{max_area:.{digits}f}"


def _run(tr, data, flags):
    try:
        return tr.triangulate(data, flags)
    except RuntimeError as e:  # the outline was validated, so this should not happen
        raise ValueError(f"Triangle could not mesh the outline ({e})") from None


def _unit_scale(outer):
    """A power of two that brings a very small or very large outline near unit size (exact scaling)."""
    e = math.frexp(diagonal(outer))[1]  # diagonal = m 2^e, 0.5 <= m < 1
    return 1.0 if -2 <= e <= 5 else 2.0 ** (-e)


def check_n_vertices(n_vertices):
    """``n_vertices`` as an int in [3, MAX_VERTICES]; ValueError otherwise."""
    ok = isinstance(n_vertices, (int, float, np.integer, np.floating)) and not isinstance(n_vertices, bool)
    if not ok or not np.isfinite(n_vertices) or int(n_vertices) != n_vertices:
        raise ValueError(f"n_vertices must be an integer, got {n_vertices!r}")
    if not 3 <= n_vertices <= MAX_VERTICES:
        raise ValueError(f"n_vertices must lie between 3 and {MAX_VERTICES:,}, got {n_vertices!r}")
    return int(n_vertices)


def check_max_area(max_area, area):
    """``max_area`` as a positive float that asks for at most about MAX_VERTICES vertices."""
    max_area = opt.positive("max_area", max_area)
    if area / max_area > 2 * MAX_VERTICES:
        raise ValueError(
            f"max_area={max_area:.3g} would give about {area / max_area / 2:.3g} vertices for a shape of area "
            f"{area:.3g}; at most {MAX_VERTICES:,} are allowed (use max_area >= {area / (2 * MAX_VERTICES):.3g})"
        )
    return float(max_area)


def _check_points(points, loops):
    """Handle points strictly inside the shape (Triangle crashed on points on the boundary), pairwise apart."""
    points = np.zeros((0, 2)) if points is None else np.atleast_2d(opt.real_array("handles", points))
    if points.ndim != 2 or points.shape[1] != 2:
        raise ValueError(f"points must have shape (k,2), got {points.shape}")
    if not len(points):
        return points
    if not np.isfinite(points).all():
        raise ValueError(f"handle {int(np.argwhere(~np.isfinite(points))[0, 0])} has NaN or infinite coordinates")
    d = distance_to_outline(points, loops)
    tol = 1e-6 * diagonal(np.vstack(loops))  # closer, Triangle makes slivers of relative area < 1e-12
    inside = points_in_polygon(points, loops) & (d > tol)
    if not inside.all():
        k = int(np.flatnonzero(~inside)[0])
        on = d[k] <= tol
        raise ValueError(
            f"handle {k} at ({points[k, 0]:.4g}, {points[k, 1]:.4g}) is {'on the boundary of' if on else 'outside'} "
            f"the shape (nearest boundary point is {d[k]:.3g} away)"
            + (f"; handles must lie at least {tol:.3g} inside" if on else "")
        )
    _check_apart(points, tol)
    return points


def _check_boundary_points(points, loops):
    """(q,2) points on the outline (within 1e-6 of the diagonal), finite; a ValueError naming ``boundary_points``."""
    if points is None:
        return np.zeros((0, 2))
    points = np.asarray(opt.real_array("boundary_points", points), float).reshape(-1, 2)
    if not np.isfinite(points).all():
        raise ValueError("boundary_points has NaN or infinite coordinates")
    if len(points):
        d = distance_to_outline(points, loops)
        tol = 1e-6 * diagonal(np.vstack(loops))
        if d.max() > tol:
            k = int(np.argmax(d))
            raise ValueError(f"boundary_points[{k}] is {d[k]:.3g} from the outline (at most {tol:.3g})")
    return points


def _check_apart(points, tol):
    """Handles closer than ``tol`` are named (Triangle made slivers of them: "150 degenerate triangles")."""
    if len(points) < 2:
        return
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points).query(points, k=2)
    close = np.flatnonzero(dist[:, 1] <= tol)
    if len(close):
        i = int(close[0])
        diff = points - points[i]
        d_i = np.sqrt(diff[:, 0] ** 2 + diff[:, 1] ** 2)
        d_i[i] = np.inf
        j = int(np.argmin(d_i))  # the kd-tree may list a coincident point before the point itself
        d = float(d_i[j])
        i, j = min(i, j), max(i, j)
        apart = "coincide" if d == 0 else f"are {d:.2g} apart"
        raise ValueError(
            f"handles {i} and {j} {apart}; merge them or move one (handles must be more than "
            f"{tol:.3g} apart, 1e-6 of the shape's diagonal)"
        )


def _resampled(loops, h, keep=None):
    """Resampled loops (the points of ``keep`` kept where they are vertices), validated again (a coarse spacing can
    make a thin part cross itself)."""
    if h is None:
        return loops
    rs = [resample(L, h, keep=keep) for L in loops]
    n = sum(len(L) for L in rs)
    if n > MAX_VERTICES:
        raise ValueError(f"resampling the outline with spacing h={h:.3g} gives {n:,} points (at most {MAX_VERTICES:,})")
    try:
        outer, holes = validate_polygon(rs[0], rs[1:])
    except ValueError as e:
        msg = f"the outline resampled with spacing h={h:.3g} is not valid ({e}); ask for more vertices"
        raise ValueError(msg) from None
    return [outer, *holes]


def triangulate(outer, holes=(), points=None, max_area=None, n_vertices=None, h=None, boundary_points=None):
    """Mesh a polygon with holes by Triangle (quality, conforming), with given points as vertices.

    Parameters
    ----------
    outer : (k,2) numpy array
        The outer boundary (either orientation).
    holes : list of (l,2) numpy array
        Hole boundaries: strictly inside ``outer``, disjoint, not nested.
    points : (p,2) numpy array, optional
        Points that must be mesh vertices (handles); find their indices with
        ``mesh.nearest_vertex(points)`` (distance 0).
    max_area : float, optional
        Maximum triangle area.
    n_vertices : int, optional
        Aim at about this many vertices, 3 to ``MAX_VERTICES`` (overrides ``max_area``; two refinement
        passes).
    h : float, optional
        Resample the outline with spacing ``h`` first (default: keep it).
    boundary_points : (q,2) numpy array, optional
        Points on the outline (within 1e-6 of the diagonal) that must be mesh vertices: inserted into the outline
        (:func:`~defop.geometry.planar.polygon.insert_on_outline`) and kept by the resampling.

    Returns
    -------
    mesh : defop.geometry.mesh.Mesh

    Raises
    ------
    ValueError
        An invalid outline (see :func:`defop.geometry.planar.polygon.validate_polygon`), points outside the shape, or
        a vertex count or area bound out of range.
    """
    outer, holes = validate_polygon(outer, holes)
    loops = [outer, *holes]
    points = _check_points(points, loops)
    keep = _check_boundary_points(boundary_points, loops)
    if len(keep):
        loops = insert_on_outline(loops, keep)
        outer = loops[0]
    area = abs(polygon_area(outer)) - sum(abs(polygon_area(H)) for H in holes)
    if n_vertices is not None:
        max_area = 1.6 * area / check_n_vertices(n_vertices)
    if max_area is not None:
        max_area = check_max_area(max_area, area)
    if h is None and max_area is not None:
        h = float(np.sqrt(4 / np.sqrt(3) * max_area))
    if h is not None:
        h = opt.positive("h", h)
    # Triangle's area flag is a plain decimal: mesh tiny or huge outlines at about unit size
    s = _unit_scale(outer)
    loops, points, area, keep = [L * s for L in loops], points * s, area * s * s, keep * s
    max_area = None if max_area is None else max_area * s * s
    h = None if h is None else h * s
    rs = _resampled(loops, h, keep)
    V, F = _triangle(rs[0], rs[1:], points, max_area)
    if n_vertices is not None:
        for _ in range(2):
            ratio = len(V) / n_vertices
            if abs(ratio - 1) < 0.04:
                break
            max_area = check_max_area(max_area * ratio, area)
            h = float(np.sqrt(4 / np.sqrt(3) * max_area))
            rs = _resampled(loops, h, keep)
            V, F = _triangle(rs[0], rs[1:], points, max_area)
    return Mesh(V / s, F)
