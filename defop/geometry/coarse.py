"""Two levels of one domain Ω: a coarse mesh of the same shape with the same handles, and the prolongation.

Multilevel training (:mod:`defop.training.multilevel`) decides each sample's minimum on a coarse mesh and refines
it once on the fine one. This module holds the geometry it needs, on raw arrays:

* :func:`coarse_planar_mesh`: Triangle from the same outline (outer loop and holes) with a larger area bound,
  the handle points kept as vertices (Triangle keeps input points exactly);
* :func:`prolongation`: the sparse matrix of barycentric coordinates of the fine vertices in the coarse elements
  (:meth:`defop.geometry.mesh.Mesh.locate`; a fine vertex just outside the coarse mesh, where the coarse outline
  cuts a corner, gets the extrapolated coordinates of the element it is least outside of, so affine maps are still
  reproduced);
* :func:`prolongate`: a coarse map to the fine mesh as a displacement, ``X_f = V_f + P (X_c - V_c)``, with the
  handle rows copied: the rest pose goes to the rest pose bit for bit (a zero displacement) and handles to handles
  bit for bit, whatever the round-off of the barycentric coordinates.

* :func:`coarse_mesh_of`: the coarse mesh of a fine one in either dimension; a tetrahedral mesh gets Kuhn cubes at
  twice the spacing, its inside test the fine mesh, the handles inserted as vertices
  (:func:`defop.geometry.volumetric.coarsening.coarse_solid_mesh`). The prolongation is the same in 2D and 3D.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .planar.meshing import triangulate
from .planar.polygon import diagonal, distance_to_outline
from .volumetric.coarsening import coarse_solid_mesh, spacing_factor

__all__ = [
    "CoarseningError",
    "OUTSIDE",
    "coarse_mesh_of",
    "coarse_planar_mesh",
    "n_parts",
    "prolongate",
    "prolongation",
]

#: a fine vertex may lie at most this many element heights outside the coarse element it is located in (the coarse
#: outline, resampled at the coarse spacing, cuts corners and the ends of thin limbs by up to about one spacing: 0.84
#: at an octopus tip at 1/8 of the vertices); farther means the coarse mesh lost a part of the shape
OUTSIDE = 1.0
#: a point within this share of the bounding-box diagonal of the outline lies on it (Triangle's own bound for points)
ON_OUTLINE = 1e-6


class CoarseningError(ValueError):
    """No coarse mesh of the same shape with the same handles exists at the asked size (the message says why)."""


def n_parts(F, n_vertices):
    """Number of connected parts of a simplicial mesh (vertices linked by shared elements).

    Parameters
    ----------
    F : (m, d + 1) int numpy array
    n_vertices : int

    Returns
    -------
    int
    """
    F = np.asarray(F)
    rows = np.repeat(F[:, 0], F.shape[1] - 1)
    cols = F[:, 1:].ravel()
    A = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, n_vertices))
    return int(connected_components(A, directed=False)[0])


def coarse_planar_mesh(loops, points, n_vertices, outline_ok=None):
    """A coarse Triangle mesh of the same planar outline with the given points as vertices.

    Parameters
    ----------
    loops : list of (k, 2) numpy array
        The outline the fine mesh was made from: outer loop first, then the holes.
    points : (h, 2) numpy array
        The handle points (rest positions); each becomes a vertex of the coarse mesh.
    n_vertices : int
        About how many vertices the coarse mesh gets.
    outline_ok : (h,) bool numpy array, optional
        The points that may lie on the outline (a fine boundary vertex where a movable handle may sit): those within
        :data:`ON_OUTLINE` of the diagonal become outline vertices. Every other point must be inside (None: all),
        as the handles of a fixed-P training: one on the outline has no coarse level.

    Returns
    -------
    mesh : defop.geometry.mesh.Mesh
    idx : (h,) int64 numpy array
        The coarse vertex at each point (at distance exactly 0).

    Raises
    ------
    CoarseningError
        No outline, Triangle refuses the outline at this spacing, or a point is not a vertex of the coarse mesh.
    """
    if not loops:
        raise CoarseningError("the shape has no outline to mesh coarsely (a mesh given as V, F)")
    points = np.asarray(points, float)
    ok = np.zeros(len(points), bool) if outline_ok is None else np.asarray(outline_ok, bool)
    on = ok & (distance_to_outline(points, loops) <= ON_OUTLINE * diagonal(np.vstack(loops)))
    try:
        mesh = triangulate(
            loops[0], list(loops[1:]), points=points[~on], n_vertices=int(n_vertices), boundary_points=points[on]
        )
    except ValueError as exc:
        raise CoarseningError(f"Triangle cannot mesh the outline with about {n_vertices} vertices: {exc}") from exc
    idx, dist = mesh.nearest_vertex(points)
    if not np.all(dist == 0):
        k = int(np.argmax(dist))
        raise CoarseningError(
            f"handle {k} is not a vertex of the coarse mesh of {mesh.n_vertices} vertices (nearest {dist[k]:.3g} away)"
        )
    return mesh, idx


def _edge_length(mesh):
    """A typical edge length of a mesh: that of a regular simplex of the median volume."""
    v = float(np.median(mesh.volumes))
    return float(np.sqrt(4 * v / np.sqrt(3))) if mesh.dim == 2 else float((6 * np.sqrt(2) * v) ** (1 / 3))


def prolongation(V_fine, coarse):
    """Barycentric coordinates of the fine vertices in the coarse elements, as a sparse matrix.

    Parameters
    ----------
    V_fine : (n, d) numpy array
        Rest positions of the fine mesh's vertices.
    coarse : defop.geometry.mesh.Mesh
        The coarse mesh (same d).

    Returns
    -------
    P : (n, n_c) scipy.sparse.csr_matrix
        Row i holds the d + 1 barycentric coordinates of fine vertex i (rows sum to 1; all ≥ 0 inside).

    Raises
    ------
    CoarseningError
        A fine vertex lies more than :data:`OUTSIDE` element heights outside the coarse mesh (the coarse mesh
        lost a part of the shape).
    """
    V_fine = np.asarray(V_fine, float)
    if V_fine.ndim != 2 or V_fine.shape[1] != coarse.dim:
        raise ValueError(f"V_fine must have shape (n, {coarse.dim}) like the coarse mesh, got {V_fine.shape}")
    elements, bary = coarse.locate(V_fine)
    # how far outside, in heights of the element: its most negative barycentric coordinate
    out = np.maximum(-bary.min(axis=1), 0.0)
    worst = int(np.argmax(out))
    if out[worst] > OUTSIDE:
        raise CoarseningError(
            f"fine vertex {worst} at {np.round(V_fine[worst], 4).tolist()} lies outside the coarse mesh by "
            f"{out[worst]:.2f} of an element (at most {OUTSIDE}): the coarse mesh loses a part of the shape"
        )
    n, k = len(V_fine), coarse.dim + 1
    rows = np.repeat(np.arange(n), k)
    return sp.csr_matrix((bary.ravel(), (rows, coarse.F[elements].ravel())), shape=(n, coarse.n_vertices))


def prolongate(P, V_fine, V_coarse, X_coarse, fine_handles, coarse_handles):
    """A coarse map on the fine mesh: ``X_f = V_f + P (X_c - V_c)``, handle rows copied from the coarse ones.

    Parameters
    ----------
    P : (n, n_c) scipy sparse matrix
        :func:`prolongation`.
    V_fine : (n, d) numpy array
    V_coarse : (n_c, d) numpy array
    X_coarse : (n_c, d) numpy array
        The coarse map.
    fine_handles, coarse_handles : (h,) int numpy array
        The same handles' vertices on both meshes (same rest positions).

    Returns
    -------
    X_fine : (n, d) numpy array
        ``V_fine`` exactly when ``X_coarse`` is ``V_coarse``; ``X_fine[fine_handles] == X_coarse[coarse_handles]``.
    """
    X = V_fine + P @ (np.asarray(X_coarse, float) - V_coarse)
    X[fine_handles] = X_coarse[coarse_handles]
    return X


def _coarse_solid(mesh, points, factor, minimum):
    """The coarse tetrahedral mesh and its handle vertices, or :class:`CoarseningError`."""
    try:
        coarse, idx = coarse_solid_mesh(mesh, points, spacing_factor(factor))
    except ValueError as exc:
        raise CoarseningError(f"no coarse Kuhn mesh of the solid: {exc}") from exc
    if coarse.n_vertices < minimum or 2 * coarse.n_vertices > mesh.n_vertices:
        raise CoarseningError(
            f"the mesh has {mesh.n_vertices} vertices: a coarse mesh of {coarse.n_vertices} (at least {minimum}, at "
            "most half) saves nothing"
        )
    return coarse, idx


def coarse_mesh_of(mesh, loops, points, factor, minimum, outline_ok=None):
    """The coarse mesh for a fine one: about ``n / factor`` vertices (at least ``minimum``), same parts.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        The fine mesh.
    loops : list of (k, 2) numpy array
        Its outline (outer first), empty for a mesh with none (a tetrahedral mesh needs none).
    points : (h, d) numpy array
        Handle points.
    factor : float
    minimum : int
    outline_ok : (h,) bool numpy array, optional
        In 2D, the points that may lie on the outline (:func:`coarse_planar_mesh`).

    Returns
    -------
    coarse : defop.geometry.mesh.Mesh
    idx : (h,) int64 numpy array
        Coarse vertex of each point.
    P : (n, n_c) scipy.sparse.csr_matrix
        :func:`prolongation`.

    Raises
    ------
    CoarseningError
        No outline (2D), a coarse mesh not at least twice smaller or with fewer than ``minimum`` vertices (3D), a lost
        or merged part, a fine vertex far outside the coarse mesh, or a handle that cannot be a coarse vertex.

    Notes
    -----
    A tetrahedral mesh gets :func:`~defop.geometry.volumetric.coarsening.coarse_solid_mesh` at the integer spacing
    ``round(factor ** (1/3))`` (at least 2), which divides the vertex count by about ``factor``.
    """
    if mesh.dim == 3:
        coarse, idx = _coarse_solid(mesh, points, factor, minimum)
    else:
        target = max(int(minimum), int(mesh.n_vertices / factor))
        if 2 * target > mesh.n_vertices:
            raise CoarseningError(
                f"the mesh has {mesh.n_vertices} vertices: a coarse mesh of {target} (at least {minimum}) saves nothing"
            )
        coarse, idx = coarse_planar_mesh(loops, points, target, outline_ok)
    parts, coarse_parts = n_parts(mesh.F, mesh.n_vertices), n_parts(coarse.F, coarse.n_vertices)
    if parts != coarse_parts:
        raise CoarseningError(f"the coarse mesh has {coarse_parts} parts where the shape has {parts}")
    return coarse, idx, prolongation(mesh.V, coarse)
