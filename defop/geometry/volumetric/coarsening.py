"""A coarse tetrahedral mesh of a solid from its fine mesh: Kuhn cubes at twice the spacing, the handles kept.

The fine meshes of :mod:`.mesher` are Kuhn cubes of side h with the boundary snapped onto the surface. The coarse
mesh is built the same way from the fine mesh alone (a stranger's tetrahedral mesh works too):

* the spacing is ``factor`` × h, h read from the data (the cube side of a Kuhn tetrahedron of the median volume,
  h³/6), and the coarse grid is aligned with the fine grid (origin at a fine vertex on it), chosen among the
  2³ parities to put the most handles on coarse grid vertices; with factor 2 every other fine grid vertex is a coarse
  vertex and the rest are midpoints of coarse Kuhn edges (the fine grid is the coarse one's edge-midpoint refinement);
* the inside test is the fine mesh itself: a coarse cube is kept when its centre lies in a fine tetrahedron; the cube
  set is cleaned (:func:`.grid.clean_cubes`) and split (:func:`.grid.cubes_to_tets`);
* the boundary is snapped onto the fine mesh's boundary surface (:func:`.mesher.snap_boundary`);
* each handle point becomes a coarse vertex exactly: the smallest coarse simplex it lies in (coordinates below
  :data:`DROP` dropped) is split at the point (a stellar split; at a vertex, or outside the coarse mesh where it cut
  off a thin end, the nearest vertex moves onto the point), and every tetrahedron keeps at least
  :data:`MIN_VOLUME` × (factor h)³/6.
"""

from __future__ import annotations

import math

import numpy as np

from ..mesh import Mesh, boundary_facets, signed_volumes
from .grid import clean_cubes, cubes_to_tets, grid_centres
from .mesher import snap_boundary
from .surface import surface_projector

__all__ = ["DROP", "MIN_VOLUME", "coarse_solid_mesh", "fine_spacing", "insert_points"]

#: a handle's barycentric coordinates below this are dropped: it is taken to lie on the face, edge or vertex spanned
#: by the others (no sliver is made for a point close to a face)
DROP = 0.1
#: every coarse tetrahedron keeps at least this fraction of the Kuhn volume (factor h)³/6 (as the fine snapping)
MIN_VOLUME = 0.02


def fine_spacing(mesh):
    """The cube side h of a Kuhn mesh: that of a tetrahedron of the median volume (h³/6), as a float."""
    return float(np.cbrt(6.0 * np.median(mesh.volumes)))


def _origin(mesh, h, points, factor):
    """A point of the fine grid (a vertex of a median tetrahedron) shifted to put the most points on the coarse grid.

    Returns
    -------
    (3,) numpy array
    """
    ref = mesh.V[mesh.F[int(np.argsort(mesh.volumes)[len(mesh.volumes) // 2])][0]]
    steps = (points - ref) / h
    on_grid = np.all(np.abs(steps - np.round(steps)) < 1e-6, axis=1)
    parity = np.mod(np.round(steps[on_grid]).astype(np.int64), factor)
    best, count = np.zeros(3, np.int64), -1
    for shift in np.ndindex(*(factor,) * 3):
        c = int(np.all(parity == np.array(shift), axis=1).sum())
        if c > count:
            best, count = np.array(shift), c
    return ref + best * h


def _kept_cubes(mesh, origin, H):
    """The cleaned coarse cubes whose centre lies in the fine mesh: (occ, lo) with two empty layers around."""
    lo_idx = np.floor((mesh.V.min(axis=0) - origin) / H).astype(np.int64) - 3
    hi_idx = np.ceil((mesh.V.max(axis=0) - origin) / H).astype(np.int64) + 3
    lo = origin + lo_idx * H
    shape = tuple(int(k) for k in hi_idx - lo_idx)
    C = grid_centres(lo, H, shape)
    _, bary = mesh.locate(C)
    keep = bary.min(axis=1) >= -1e-9
    occ = np.transpose(keep.reshape(shape[::-1]), (2, 1, 0))
    if not occ.any():
        raise ValueError(f"no coarse cube of side {H:.3g} has its centre inside the fine mesh")
    return clean_cubes(occ), lo


def _movable_vertex(V, T, p, floor, reach, taken, tries=8):
    """The nearest vertex within ``reach`` of p (of the ``tries`` nearest, not ``taken``) that can move onto p with
    every tetrahedron at least ``floor`` thick, as a (1,) int array; None if none can."""
    d2 = ((V - p) ** 2).sum(axis=1)
    for v in np.argsort(d2, kind="stable")[:tries]:
        if d2[v] > reach * reach:
            break
        if v in taken:
            continue
        W = V.copy()
        W[v] = p
        around = np.any(T == v, axis=1)
        if signed_volumes(W, T[around]).min() >= floor:
            return np.array([v])
    return None


def insert_points(V, T, points, floor, drop=DROP, far=0.05):
    """Make each point a vertex of a tetrahedral mesh: the smallest simplex it lies in is split at it.

    Parameters
    ----------
    V : (n, 3) numpy array
    T : (m, 4) int numpy array
        Positively oriented tetrahedra.
    points : (h, 3) numpy array
        Points in the mesh or near it, distinct.
    floor : float
        The smallest tetrahedron volume the result may have.
    drop : float
        Barycentric coordinates below this are dropped (the point is taken to lie on the simplex of the others). A
        point more than ``drop`` of an element height outside the mesh is reached by moving the nearest vertex.
    far : float
        A point outside the mesh farther than this fraction of the bounding-box diagonal from every vertex is refused.

    Returns
    -------
    V : (n', 3) numpy array
    T : (m', 4) int numpy array
    idx : (h,) int64 numpy array
        The vertex at each point (``V[idx] == points`` exactly).

    Raises
    ------
    ValueError
        A point far outside the mesh, or a split that leaves a tetrahedron thinner than ``floor`` (the message
        names the point).
    """
    V, T = np.array(V, float), np.array(T, np.int64)
    idx = np.empty(len(points), np.int64)
    for k, p in enumerate(np.asarray(points, float)):
        mesh = Mesh(V, T)
        e, bary = mesh.locate(p[None])
        S = T[e[0]][bary[0] >= drop]
        if bary[0].min() < -drop:  # outside (a thin end cut off): a near vertex moves out onto the point
            S = _movable_vertex(V, T, p, floor, far * mesh.bbox_diagonal, idx[:k])
            if S is None:
                raise ValueError(f"point {k} at {np.round(p, 4).tolist()} lies outside the coarse mesh")
        if len(S) == 1 and S[0] in idx[:k]:
            raise ValueError(f"points {int(np.flatnonzero(idx[:k] == S[0])[0])} and {k} fall on one coarse vertex")
        if len(S) == 1:  # at a vertex: the vertex moves onto the point
            V[S[0]], idx[k] = p, S[0]
        else:  # stellar split: every tetrahedron holding S becomes |S| tetrahedra, one vertex of S replaced by p
            V, idx[k] = np.vstack([V, p]), len(V)
            around = np.isin(T, S).sum(axis=1) == len(S)
            children = [np.where(T[around] == s, idx[k], T[around]) for s in S]
            T = np.vstack([T[~around], *children])
        vol = signed_volumes(V, T)
        if vol.min() < floor:
            raise ValueError(
                f"point {k} at {np.round(p, 4).tolist()} cannot become a vertex: a tetrahedron would have volume "
                f"{vol.min():.3g} (at least {floor:.3g})"
            )
    return V, T, idx


def coarse_solid_mesh(mesh, points, factor=2):
    """A coarse Kuhn mesh of the solid a fine tetrahedral mesh fills, with the given points as vertices.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        The fine tetrahedral mesh.
    points : (h, 3) numpy array
        The handle points (rest positions); each becomes a vertex of the coarse mesh.
    factor : int
        The coarse cube side in fine cube sides.

    Returns
    -------
    coarse : defop.geometry.mesh.Mesh
    idx : (h,) int64 numpy array
        The coarse vertex at each point (at distance exactly 0).

    Raises
    ------
    ValueError
        No cube centre inside, or a point that cannot become a vertex.
    """
    points = np.asarray(points, float)
    h = fine_spacing(mesh)
    H = factor * h
    occ, lo = _kept_cubes(mesh, _origin(mesh, h, points, factor), H)
    V, T = cubes_to_tets(occ, lo, H)
    B = np.unique(boundary_facets(T))
    target = V.copy()
    target[B] = surface_projector(mesh.V, boundary_facets(mesh.F))(V[B])
    V = snap_boundary(V, T, target, H, 0.1)
    V, T, idx = insert_points(V, T, points, MIN_VOLUME * H**3 / 6)
    return Mesh(V, T), idx


def spacing_factor(factor):
    """The integer coarse spacing (in fine spacings) that divides the vertex count by about ``factor`` in 3D."""
    return max(2, int(round(math.pow(factor, 1 / 3))))
