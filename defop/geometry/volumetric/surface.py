"""Closed triangle surfaces: validation, inside test, tetrahedral meshing and embedding.

A surface is ``V (n, 3)`` and ``F (k, 3)``. :func:`check_surface` rejects what cannot bound a solid:
an open surface, an edge in more than two triangles, inconsistent orientation, a pinched vertex, and
triangles that cross each other (:func:`self_intersections`); it judges the surface scaled to a unit
bounding-box diagonal, so the supported coordinates (:data:`COORDINATE_RANGE`: magnitudes up to 1e50, a
diagonal of at least 1e-50) are all judged alike. :func:`read_surface` reads PLY, STL, OBJ and OFF files
(:mod:`defop.geometry.surface_files`: counts checked before anything is allocated, STL welded). Inside is
decided by libigl's generalised winding number (``igl.winding_number``, core libigl, MPL-2.0; exact, not the fast
approximation), the boundary of the tetrahedral mesh is snapped to the closest surface point
(``igl.point_mesh_squared_distance``); :meth:`defop.geometry.mesh.Mesh.locate` gives each surface vertex
its tetrahedron and barycentric coordinates, so the fine surface can be drawn deformed. The surface is meshed
from canonical coordinates (:func:`canonical_surface`: rounded to float32, then to a grid of about 1e-6 of the
diagonal), so copies of it that differ by float rounding (an STL and its OBJ) give one mesh. An open surface's
error names the gap between its boundary vertices and the ``weld_tolerance`` that would close it (:func:`weld_hint`).

libigl is compiled code without run-time CPU dispatch; its winding number uses libm's ``atan2``, whose
last bit could differ between libm builds. Only a cube centre within about 1e-15 of winding number 1/2
(on the surface) could change side, and a centre on the surface is not a case the grid produces on
purpose.
"""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..mesh import check_closed_surface, signed_volumes
from ..surface_files import bbox_diagonal, read_surface_file
from .mesher import grid_spacing, tet_mesh

__all__ = [
    "check_surface",
    "self_intersections",
    "surface_mesh",
    "read_surface",
    "normalised",
    "COORDINATE_RANGE",
    "enclosed_volume",
    "inside_surface",
    "surface_projector",
    "surface_parts",
    "EmbeddedSurface",
    "weld_hint",
    "float32_canonical",
    "FLOAT32_RANGE",
    "canonical_surface",
    "SNAP_TOLERANCE",
]


def read_surface(path, weld_tolerance=None):
    """A triangle surface from a PLY, STL, OBJ or OFF file (numpy readers, counts checked before allocation).

    STL corners at exactly the same coordinates are welded (a closed STL reads as a closed surface);
    ``weld_tolerance`` also merges vertices within that fraction of the bounding-box diagonal, and
    refuses welding that creates degenerate or non-manifold triangles. See
    :func:`defop.geometry.surface_files.read_surface_file`, which documents the checks.

    Returns
    -------
    surface : defop.geometry.surface_files.SurfaceFile
        Unpacks as ``V (n, 3), F (k, 3) = surface``; ``surface.welded`` is how many vertices were merged.

    Raises
    ------
    ValueError
        A missing, unreadable, empty, malformed or oversized file, or a directory; the message names the file.
    """
    return read_surface_file(path, weld_tolerance=weld_tolerance)


#: the supported coordinates: every |coordinate| at most the upper bound, the bounding-box diagonal at
#: least the lower. Within it, element volumes (diagonal³), squared distances and the solver's energies stay
#: far inside float64's normal range (about 2.2e-308 to 1.8e308), and :func:`check_surface` judges a
#: surface on coordinates normalised to a unit diagonal, so a box scaled by 1e-30 or 1e30 is judged like
#: the unit box. Scaling is free; distance from the origin is not: a surface about 1e15 of its diagonals
#: from the origin has lost float64's precision there, and its collapsed triangles are called zero-area.
COORDINATE_RANGE = (1e-50, 1e50)


def normalised(V, what="the surface"):
    """V moved and scaled to a unit bounding-box diagonal, centred at 0, after the range check.

    Parameters
    ----------
    V : (n, 3) finite numpy array

    Returns
    -------
    Vn : (n, 3) numpy array
        ``(V - centre) / diagonal``.
    diagonal : float

    Raises
    ------
    ValueError
        A coordinate above ``COORDINATE_RANGE[1]`` in magnitude or a diagonal below ``COORDINATE_RANGE[0]``
        (also all vertices at one point).
    """
    lo, hi = COORDINATE_RANGE
    big = float(np.abs(V).max(initial=0.0))
    if big > hi:
        raise ValueError(
            f"{what} has a coordinate of magnitude {big:.3g}; supported coordinates are at most "
            f"{hi:g} (defop.geometry.volumetric.surface.COORDINATE_RANGE): rescale it"
        )
    diag = bbox_diagonal(V)
    if not diag >= lo:
        raise ValueError(
            f"{what} has a bounding-box diagonal of {diag:.3g}; the supported diagonal is at least "
            f"{lo:g} (defop.geometry.volumetric.surface.COORDINATE_RANGE): rescale it"
        )
    centre = 0.5 * (V.min(axis=0) + V.max(axis=0))
    return (V - centre) / diag, diag


def _as_surface(V, F):
    V = np.asarray(V, dtype=float)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4:
        raise ValueError(f"V must have shape (n,3) with n >= 4 (a closed surface), got {np.shape(V)}")
    if not np.isfinite(V).all():
        raise ValueError(
            f"V has non-finite (NaN or inf) rows, first at row {int(np.flatnonzero(~np.isfinite(V).all(1))[0])}"
        )
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or len(F) < 4:
        raise ValueError(f"F must have shape (k,3) with k >= 4 triangles (a closed surface), got {np.shape(F)}")
    if not np.issubdtype(F.dtype, np.integer) or F.min() < 0 or F.max() >= len(V):
        raise ValueError(
            f"F must hold integer vertex indices from 0 to {len(V) - 1}, got {F.dtype} in [{F.min()}, {F.max()}]"
        )
    F = F.astype(np.int64)
    unused = np.flatnonzero(np.bincount(F.ravel(), minlength=len(V)) == 0)
    if len(unused):
        raise ValueError(
            f"{len(unused)} surface vertices are in no triangle, first is vertex {int(unused[0])}; remove them"
        )
    return V, F


def _triangle_areas2(V, F):
    """Twice the area of every triangle, squared (element-wise)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    n = np.column_stack(
        [
            e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
            e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
            e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0],
        ]
    )
    return n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1] + n[:, 2] * n[:, 2]


def enclosed_volume(V, F):
    """Signed volume enclosed by a closed triangle surface (positive for outward normals)."""
    return float(signed_volumes(np.vstack([V, V.mean(axis=0)]), np.column_stack([np.full(len(F), len(V)), F])).sum())


def _candidate_pairs(V, F):
    """Pairs (i < j) of triangles whose bounding boxes overlap and that share no vertex: a hash grid."""
    P = V[F]
    lo, hi = P.min(axis=1), P.max(axis=1)
    cell = float(np.median((hi - lo).max(axis=1))) or 1.0
    a, b = np.floor(lo / cell).astype(np.int64), np.floor(hi / cell).astype(np.int64)
    buckets = defaultdict(list)
    for t in range(len(F)):
        for i in range(a[t, 0], b[t, 0] + 1):
            for j in range(a[t, 1], b[t, 1] + 1):
                for k in range(a[t, 2], b[t, 2] + 1):
                    buckets[i, j, k].append(t)
    pairs = set()
    for ts in buckets.values():
        for x in range(len(ts)):
            for y in range(x + 1, len(ts)):
                pairs.add((ts[x], ts[y]))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    pairs = np.array(sorted(pairs), dtype=np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    overlap = ((lo[i] <= hi[j]) & (lo[j] <= hi[i])).all(axis=1)
    share = (F[i][:, :, None] == F[j][:, None, :]).any(axis=(1, 2))
    return pairs[overlap & ~share]


def surface_parts(F):
    """(k,) int numpy array: the connected part (by shared vertices) of every triangle, numbered from 0."""
    n = int(F.max()) + 1
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]]])
    G = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    return connected_components(G, directed=False)[1][F[:, 0]]


def self_intersections(V, F, limit=1, within_parts_only=False):
    """Pairs of triangles that cross each other, up to ``limit`` of them.

    Candidate pairs come from a hash grid of bounding boxes; each is tested exactly by libigl's
    ``tri_tri_intersection_test_3d`` (Guigue–Devillers, core libigl). Triangles that share a vertex
    are not tested: a surface folded through itself at one vertex, or two triangles overlapping
    across a shared edge, passes this check (the orientation and manifold checks catch many of these).

    Parameters
    ----------
    V : (n, 3) numpy array
    F : (k, 3) int numpy array
    limit : int
        Stop after this many intersecting pairs.
    within_parts_only : bool
        Test only pairs in the same connected part (:func:`surface_parts`): closed parts may overlap.

    Returns
    -------
    pairs : (p, 2) int numpy array
        Triangle index pairs, p ≤ limit.
    """
    found = []
    pairs = _candidate_pairs(V, F)
    if within_parts_only:
        part = surface_parts(F)
        pairs = pairs[part[pairs[:, 0]] == part[pairs[:, 1]]]
    for i, j in pairs:
        p = [V[F[i, c]][None] for c in range(3)] + [V[F[j, c]][None] for c in range(3)]
        if igl.tri_tri_intersection_test_3d(*p)[0]:
            found.append((int(i), int(j)))
            if len(found) >= limit:
                break
    return np.array(found, dtype=np.int64).reshape(-1, 2)


def check_surface(V, F, self_intersection=True, overlapping_parts=False):
    """A closed, oriented, manifold, non-self-intersecting triangle surface, outward-oriented.

    Parameters
    ----------
    V : (n, 3) array-like
    F : (k, 3) int array-like
    self_intersection : bool
        Test for triangles crossing each other (:func:`self_intersections`, which documents its limit).
    overlapping_parts : bool
        Allow separate closed parts (connected components) to cross each other: the solid is their
        union (the winding number is ≥ 1/2 inside any part). Each part must still not cross itself.

    Returns
    -------
    V : (n, 3) numpy array
    F : (k, 3) int numpy array
        Oriented so that normals point out of the solid (flipped if the input pointed in).

    Raises
    ------
    ValueError
        Wrong shapes or indices, unused vertices, coordinates outside :data:`COORDINATE_RANGE`,
        zero-area triangles, an open or non-manifold surface, inconsistent orientation, a pinched
        vertex, or two triangles that cross; the message names the edge, vertex or triangles.

    Notes
    -----
    The tests run on the surface moved and scaled to a unit bounding-box diagonal (:func:`normalised`),
    so their tolerances are relative: a closed box scaled by 1e-30 or 1e30 passes like the unit box.
    """
    V, F = _as_surface(V, F)
    Vn = normalised(V)[0]  # every test below is on a unit diagonal: the same verdict at any supported scale
    a2 = _triangle_areas2(Vn, F)
    ext = np.ptp(Vn, axis=0).max()
    tiny = a2 <= (1e-12 * ext * ext) ** 2
    if tiny.any():
        raise ValueError(
            f"{int(tiny.sum())} surface triangles have zero area, first is triangle {int(np.flatnonzero(tiny)[0])}"
        )
    try:
        check_closed_surface(F, what="the surface")
    except ValueError as exc:
        raise ValueError(f"{exc}{weld_hint(Vn, F)}") from None
    if enclosed_volume(Vn, F) < 0:
        F = np.ascontiguousarray(F[:, [0, 2, 1]])
    if self_intersection:
        bad = self_intersections(Vn, F, within_parts_only=overlapping_parts)
        if len(bad):
            i, j = (int(x) for x in bad[0])
            hint = (
                ""
                if overlapping_parts
                else " (if the surface is several closed parts meant as their union, pass overlapping_parts=True)"
            )
            raise ValueError(f"the surface intersects itself: triangles {i} and {j} cross{hint}")
    return V, F


def weld_hint(Vn, F):
    """For an open surface on a unit diagonal: the gap between its boundary vertices and the weld_tolerance that
    would close it (``""`` when no edge is on a boundary).

    Each boundary vertex (on an edge of one triangle) is paired with the nearest other boundary vertex that
    shares no edge with it (among its 7 nearest); the largest of those distances is the gap. A gap of 0 means
    unwelded copies of vertices (``weld_tolerance=0`` merges them); a gap of 0.05 or more (none found, or half
    the largest tolerance) is a hole, which welding cannot close. The tolerance offered is twice the gap.
    """
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(E, axis=0, return_counts=True)
    B = np.unique(edges[counts == 1])
    if len(B) < 2:
        return ""
    k = min(len(B), 8)
    dist, near = cKDTree(Vn[B]).query(Vn[B], k=k)
    a, b = np.repeat(B, k - 1), B[near[:, 1:]].ravel()
    linked = np.isin(np.minimum(a, b) * len(Vn) + np.maximum(a, b), edges[:, 0] * len(Vn) + edges[:, 1])
    dist = np.where(linked.reshape(len(B), k - 1), np.inf, dist[:, 1:])  # a vertex of its own triangles: no crack
    gap = float(dist.min(axis=1).max())
    if not gap < 0.05:
        return "; its boundary vertices are not copies of each other: a hole, which weld_tolerance cannot close"
    if gap == 0:
        return "; its boundary vertices have exact copies: read the file with weld_tolerance=0 to merge them"
    e = 10.0 ** np.floor(np.log10(2 * gap))
    tol = float(f"{np.ceil(2 * gap / e) * e:.1g}")  # twice the gap, rounded up to one digit
    return (
        f"; every boundary vertex lies within {gap:.2g} × the bounding-box diagonal of another: read the file "
        f"with weld_tolerance={tol:g} (read_surface or from_surface) to merge them"
    )


def inside_surface(V, F):
    """``inside(P (k, 3)) -> (k,) bool``: generalised winding number of the surface ≥ 1/2."""

    def inside(P):
        return np.asarray(igl.winding_number(V, F, np.ascontiguousarray(P, dtype=float))) >= 0.5

    return inside


def surface_projector(V, F):
    """``project(P (k, 3)) -> (k, 3)``: the closest point of the surface to each point (libigl)."""

    def project(P):
        return np.asarray(igl.point_mesh_squared_distance(np.ascontiguousarray(P, dtype=float), V, F)[2])

    return project


#: the coordinates :func:`float32_canonical` rounds: magnitudes up to the upper bound, a diagonal of at least the lower
FLOAT32_RANGE = (1e-30, 1e37)


def float32_canonical(V):
    """V rounded to float32 (as float64), when its coordinates are inside :data:`FLOAT32_RANGE`; else V unchanged.

    The mesher is not continuous in the surface (a tetrahedron near its thickness floor halves a vertex's move),
    so two copies of one surface that differ by float rounding, an STL (float32) and its OBJ (float64), could
    mesh differently. Rounded to float32 first, every surface whose coordinates round to the same float32 values
    meshes identically, bit for bit; a perturbation that changes a float32 value may still change the mesh.
    """
    lo, hi = FLOAT32_RANGE
    if len(V) and float(np.abs(V).max()) <= hi and bbox_diagonal(V) >= lo:
        return V.astype(np.float32).astype(np.float64)
    return V


#: the canonical grid of a surface before meshing (:func:`canonical_surface`), as a fraction of its bounding-box
#: diagonal: the grid spacing is the largest power of two not above this fraction
SNAP_TOLERANCE = 1e-6


def canonical_surface(V):
    """The coordinates a surface is meshed from: rounded to float32 (:func:`float32_canonical`), then to the nearest
    multiple of g, the largest power of two at most :data:`SNAP_TOLERANCE` × the bounding-box diagonal.

    The mesher is not continuous in the surface (a tetrahedron near its thickness floor halves a vertex's move, a
    cube centre near the surface changes side), so two copies of one surface that differ in the last digits could
    mesh differently. Stable here means: **copies with the same canonical coordinates mesh identically, bit for
    bit** (the same tetrahedra, the same cache entries). That holds for

    - copies that round to the same float32 values (an STL, which stores float32, and an OBJ or PLY of it written
      with 9 significant digits), and
    - any copy of a surface on the grid (canonical coordinates are) perturbed by less than g/2 minus the float32
      rounding of its coordinates: by less than 1.9e-7 × the diagonal when no coordinate exceeds the diagonal in
      magnitude (g/2 ≥ 2.5e-7 × the diagonal; float32 rounds by at most 6e-8 × a coordinate).

    It is not a promise for every perturbation of every surface: a coordinate within ε of a midpoint between two
    grid values (probability about 2ε/g per coordinate, for a random perturbation of size ε) rounds the other way,
    and the mesh may then differ; so may g, when the diagonal crosses a power of two. The moves are at most g/2,
    five orders of magnitude below the mesh size at the default 2,000 vertices.

    Parameters
    ----------
    V : (n, 3) numpy array

    Returns
    -------
    V : (n, 3) float64 numpy array
    """
    V = float32_canonical(np.asarray(V, float))
    diag = bbox_diagonal(V) if len(V) else 0.0
    if not (math.isfinite(diag) and diag > 0):
        return V
    g = math.ldexp(1.0, math.frexp(SNAP_TOLERANCE * diag)[1] - 1)  # the power of two in (tol·diag/2, tol·diag]
    return np.round(V / g) * g


def surface_mesh(V, F, n_vertices=2000, min_volume=0.1, checked=False, overlapping_parts=False):
    """A tetrahedral mesh of the solid bounded by a closed triangle surface.

    Parameters
    ----------
    V, F : (n, 3) numpy array, (k, 3) int numpy array
        The closed surface's vertices and triangles.
    n_vertices : int
        About how many tetrahedral mesh vertices.
    min_volume : float
        Snapping keeps every tetrahedron's volume at least this fraction of h³/6.
    checked : bool
        Whether (V, F) already passed :func:`check_surface` (else it is checked here).
    overlapping_parts : bool
        See :func:`check_surface`.

    Returns
    -------
    mesh : defop.geometry.mesh.Mesh
        Meshed from the surface's canonical coordinates (:func:`canonical_surface`: rounded to float32, then to
        a grid of about 1e-6 of the diagonal): copies with the same canonical coordinates (an STL and its OBJ, a
        copy perturbed by less than 2.4e-7 × the diagonal of a surface on that grid) give the same mesh.
    """
    if not checked:
        V, F = check_surface(V, F, overlapping_parts=overlapping_parts)
    V = canonical_surface(V)
    bbox = np.array([V.min(axis=0), V.max(axis=0)])
    inside = inside_surface(V, F)
    h = grid_spacing(inside, bbox, n_vertices)
    return tet_mesh(inside, bbox, h, project=surface_projector(V, F), min_volume=min_volume)


@dataclasses.dataclass(eq=False)
class EmbeddedSurface:
    """A fine closed surface carried by a tetrahedral mesh: each vertex at fixed barycentric coordinates.

    Attributes
    ----------
    V : (k, 3) numpy array
        Rest positions of the surface vertices.
    F : (l, 3) int numpy array
        Surface triangles.
    elements : (k,) int numpy array
        The tetrahedron of each surface vertex (:meth:`defop.geometry.mesh.Mesh.locate`).
    bary : (k, 4) numpy array
        Its barycentric coordinates there (negative where the vertex is outside the tetrahedral mesh).
    tets : (m, 4) int numpy array
        The tetrahedra of the carrying mesh.
    """

    V: np.ndarray
    F: np.ndarray
    elements: np.ndarray
    bary: np.ndarray
    tets: np.ndarray

    @classmethod
    def embed(cls, mesh, V, F):
        """Embed the surface (V (k,3), F (l,3)) in ``mesh`` (a tetrahedral defop.geometry.mesh.Mesh)."""
        elements, bary = mesh.locate(V)
        return cls(np.asarray(V, float), np.asarray(F, np.int64), elements, bary, mesh.F)

    def deform(self, X):
        """(k, 3) numpy array: the surface vertices under the piecewise-linear map X (n, 3) of the tetrahedra."""
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[1] != 3 or len(X) <= self.tets.max():
            raise ValueError(f"X must have shape (n,3) with a row per mesh vertex, got {X.shape}")
        P = X[self.tets[self.elements]]  # (k, 4, 3)
        return (self.bary[:, :, None] * P).sum(axis=1)
