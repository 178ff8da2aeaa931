"""Tetrahedral meshes of a solid given by an inside test: kept Kuhn cubes, boundary snapped to the surface.

The route is procedural (no mesher from a registry): a regular grid of cubes of side h, each split
into 6 Kuhn tetrahedra (:mod:`.grid`), keeps the cubes whose centre is inside, is cleaned into one
solid with a manifold boundary, and its boundary vertices are moved onto the surface (the zero set
of a field, or the closest point of a triangle surface) as far as every tetrahedron keeps a volume of
at least ``min_volume`` × h³/6. TetGen (AGPL) and libigl's ``igl.copyleft`` (GPL) are not used.

Every step is integer logic or element-wise arithmetic (no BLAS, no transcendental function), so the
mesh is the same on every CPU (tests/test_reproducible_meshes.py runs it under three OpenBLAS kernels).
"""

from __future__ import annotations

import math

import numpy as np

from ..mesh import Mesh, boundary_facets, signed_volumes
from .grid import clean_cubes, cubes_to_tets, grid_centres

__all__ = ["tet_mesh", "grid_spacing", "snap_boundary", "field_projector", "round_spacing"]


def round_spacing(h):
    """h rounded to 24 significant bits: a last-bit difference of ``**`` between libm builds vanishes."""
    m, e = math.frexp(h)
    return math.ldexp(round(m * 2**24) / 2**24, e)


def _grid(bbox, h, pad=3):
    lo = np.asarray(bbox[0], float) - pad * h
    hi = np.asarray(bbox[1], float) + pad * h
    shape = tuple(int(math.ceil((hi[k] - lo[k]) / h)) for k in range(3))
    return lo, shape


def _check_bbox(bbox):
    bbox = np.asarray(bbox, float)
    if bbox.shape != (2, 3) or not np.isfinite(bbox).all() or not (bbox[1] > bbox[0]).all():
        raise ValueError(f"bbox must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] with max > min, got {bbox.tolist()}")
    return bbox


def occupied_cubes(inside, bbox, h):
    """The cleaned cube set of a solid: (occ (nx,ny,nz) bool, lo (3,)); see :func:`.grid.clean_cubes`."""
    lo, shape = _grid(bbox, h)
    keep = np.asarray(inside(grid_centres(lo, h, shape)), bool)
    occ = np.transpose(keep.reshape(shape[::-1]), (2, 1, 0))
    if not occ.any():
        raise ValueError(f"no cube of side {h:.3g} has its centre inside the solid: use a smaller spacing")
    return clean_cubes(occ), lo


def _n_vertices(inside, bbox, h):
    occ, lo = occupied_cubes(inside, bbox, h)
    return len(cubes_to_tets(occ, lo, h)[0])


def grid_spacing(inside, bbox, n_vertices, coarse=(32, 48)):
    """The cube side h that gives about ``n_vertices`` mesh vertices.

    The vertex count is measured on two coarse grids (``coarse`` cubes along the longest side) and
    fitted by n(h) = a/h³ + b/h² (volume and surface terms), which is solved for ``n_vertices`` by
    bisection. Rounded by :func:`round_spacing`.
    """
    bbox = _check_bbox(bbox)
    if not (isinstance(n_vertices, (int, np.integer)) and n_vertices >= 8):
        raise ValueError(f"n_vertices must be an integer >= 8, got {n_vertices!r}")
    ext = float((bbox[1] - bbox[0]).max())
    h1, h2 = (round_spacing(ext / c) for c in coarse)
    n1, n2 = _n_vertices(inside, bbox, h1), _n_vertices(inside, bbox, h2)
    # n = a/h^3 + b/h^2 through both points: n h^3 = a + b h
    b = (n1 * h1 * h1 * h1 - n2 * h2 * h2 * h2) / (h1 - h2)
    a = n1 * h1 * h1 * h1 - b * h1
    if a <= 0 or b < 0:  # a very round or very coarse solid: the volume term alone
        a, b = n2 * h2 * h2 * h2, 0.0
    lo, hi = 1e-6 * ext, ext
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if a / (mid * mid * mid) + b / (mid * mid) > n_vertices:
            lo = mid
        else:
            hi = mid
    return round_spacing(0.5 * (lo + hi))


def snap_boundary(V, T, target, h, min_volume=0.1, max_move=1.0, grow_rounds=6):
    """Move the boundary vertices toward their targets while every tetrahedron stays thick.

    Parameters
    ----------
    V : (n, 3) numpy array
    T : (m, 4) int numpy array
        Positively oriented tetrahedra.
    target : (n, 3) numpy array
        Where each vertex would go (only boundary vertices should differ from V).
    h : float
        Grid spacing: the rest volume of a tetrahedron is h³/6.
    min_volume : float
        Every tetrahedron keeps a volume of at least ``min_volume`` × h³/6.
    max_move : float
        No vertex moves farther than ``max_move`` × h.
    grow_rounds : int
        Rounds in which held-back vertices try to go halfway further.

    Returns
    -------
    X : (n, 3) numpy array

    Notes
    -----
    Each vertex moves a fraction t of its way (t = 1 at first); the vertices of a tetrahedron that
    got too thin have their t halved, and set to 0 below 1/64, until no tetrahedron is too thin. A
    tetrahedron whose vertices are all back at t = 0 is a Kuhn tetrahedron again, so this ends. Then,
    ``grow_rounds`` times, every held-back vertex tries to go halfway to t = 1; the vertices of
    tetrahedra that get too thin go back (until none does), so every tetrahedron stays thick.
    """
    D = np.asarray(target, float) - V
    length = np.sqrt(D[:, 0] * D[:, 0] + D[:, 1] * D[:, 1] + D[:, 2] * D[:, 2])
    reach = max_move * h  # longer moves are cut to this length (no division by a zero length: no overflow)
    D = D * np.divide(reach, length, out=np.ones_like(length), where=length > reach)[:, None]
    floor = min_volume * h * h * h / 6
    t = _shrink_until_thick(V, T, D, np.ones(len(V)), floor)
    for _ in range(grow_rounds):  # then let the held-back vertices go further, where that stays thick
        t = _shrink_until_thick(V, T, D, t, floor, np.minimum(1.0, t + 0.5 * (1.0 - t)))
    return V + t[:, None] * D


def _shrink_until_thick(V, T, D, t, floor, t_try=None):
    """Fractions t (n,) with every tetrahedron of V + t D at least ``floor`` thick.

    Without ``t_try``: halve the t of the vertices of thin tetrahedra (0 below 1/64) until none is thin.
    With it: try ``t_try``, and put the vertices of thin tetrahedra back to ``t`` (feasible) until none is.
    """
    t = t.copy()
    cur = t if t_try is None else t_try.copy()
    for _ in range(10 * len(V) + 10):
        bad = signed_volumes(V + cur[:, None] * D, T) < floor
        if not bad.any():
            return cur
        verts = np.unique(T[bad])
        if t_try is None:
            cur[verts] *= 0.5
            cur[cur < 1 / 64] = 0.0
        else:
            cur[verts] = t[verts]
    return np.zeros(len(V)) if t_try is None else t  # not reached in practice: t = 0 is the grid


def field_projector(field, h, iterations=4):
    """A function moving points onto the zero set of ``field`` by Newton steps along its gradient.

    The gradient is a central difference with step h/1000; element-wise arithmetic only.

    Returns
    -------
    project : callable, ``project(P (k, 3)) -> (k, 3)``
    """
    step = h / 1000

    def project(P):
        P = np.array(P, float)
        for _ in range(iterations):
            f = field(P)
            g = np.empty_like(P)
            for a in range(3):
                e = np.zeros(3)
                e[a] = step
                g[:, a] = (field(P + e) - field(P - e)) / (2 * step)
            gg = g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2]
            P = P - (f / np.maximum(gg, 1e-12))[:, None] * g
        return P

    return project


def tet_mesh(inside, bbox, h, project=None, min_volume=0.1):
    """A tetrahedral mesh of a solid: Kuhn cubes inside, boundary snapped onto the surface.

    Parameters
    ----------
    inside : callable
        ``inside(P (k, 3)) -> (k,) bool``: whether each point is in the solid.
    bbox : (2, 3) array-like
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` around the solid.
    h : float
        Cube side.
    project : callable, optional
        ``project(P (k, 3)) -> (k, 3)``: the nearest surface point of each point. Without it the
        boundary stays on the grid (a voxel solid).
    min_volume : float
        Snapping keeps every tetrahedron's volume at least this fraction of h³/6.

    Returns
    -------
    mesh : defop.geometry.mesh.Mesh
        Vertices (n, 3) and tetrahedra (m, 4); validated (positive volumes, closed manifold boundary).
    """
    bbox = _check_bbox(bbox)
    if not (isinstance(h, (int, float)) and math.isfinite(h) and h > 0):
        raise ValueError(f"h must be a positive number, got {h!r}")
    occ, lo = occupied_cubes(inside, bbox, h)
    V, T = cubes_to_tets(occ, lo, h)
    if project is not None:
        B = np.unique(boundary_facets(T))
        target = V.copy()
        target[B] = project(V[B])
        V = snap_boundary(V, T, target, h, min_volume)
    return Mesh(V, T)
