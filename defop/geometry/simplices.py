"""The elements of a simplicial mesh: their names, facets, signed volumes and the cotangent Laplacian.

Element-wise arithmetic (no BLAS), so the same bits on every CPU; one code path for triangles (d = 2) and
tetrahedra (d = 3).
"""

from __future__ import annotations

import igl
import numpy as np

from .surface_files import bbox_diagonal

__all__ = [
    "ELEMENT",
    "ELEMENTS",
    "FACETS",
    "simplex_volumes",
    "signed_volumes",
    "signed_areas",
    "SAFE_DIAGONAL",
    "cotangent_laplacian",
    "element_facets",
    "boundary_facets",
    "degenerate_scale",
]

#: the name of an element of a d-dimensional mesh
ELEMENT = {2: "triangle", 3: "tetrahedron"}
#: the plural, for messages
ELEMENTS = {2: "triangles", 3: "tetrahedra"}

#: facet j of an element is the one opposite its vertex j, ordered so that it faces outward:
#: for a positive element, the simplex ``(p, *facet)`` is positive exactly when p is on the element's side
FACETS = {
    2: np.array([[1, 2], [2, 0], [0, 1]]),
    3: np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]),
}


def simplex_volumes(P0, P):
    """Signed volume of the simplices (P0, P[:, 0], ..., P[:, d-1]); element-wise, no BLAS.

    P0 : (m, d), P : (m, d, d) (the other vertices). Area in 2D, volume in 3D.
    """
    d = P0.shape[1]
    e = [P[:, i] - P0 for i in range(d)]
    if d == 2:
        return 0.5 * (e[0][:, 0] * e[1][:, 1] - e[0][:, 1] * e[1][:, 0])
    c0 = e[1][:, 1] * e[2][:, 2] - e[1][:, 2] * e[2][:, 1]
    c1 = e[1][:, 2] * e[2][:, 0] - e[1][:, 0] * e[2][:, 2]
    c2 = e[1][:, 0] * e[2][:, 1] - e[1][:, 1] * e[2][:, 0]
    return (e[0][:, 0] * c0 + e[0][:, 1] * c1 + e[0][:, 2] * c2) / 6.0


def signed_volumes(V, F):
    """Signed volume of every element: the area of a triangle in 2D, the volume of a tetrahedron in 3D.

    Parameters
    ----------
    V : (n, d) numpy array
        Vertex positions, d = 2 or 3.
    F : (m, d + 1) numpy int array
        Triangles (d = 2) or tetrahedra (d = 3).

    Returns
    -------
    vol : (m,) numpy array
        Positive for counter-clockwise triangles and positively oriented tetrahedra (det J > 0),
        negative for flipped ones. Element-wise arithmetic: the same bits on every CPU.

    Raises
    ------
    ValueError
        F does not hold integer indices from 0 to n - 1 (a negative index would wrap around silently);
        the message names the element, the index and the vertex count.
    """
    V = np.asarray(V, dtype=float)
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != V.shape[-1] + 1:
        raise ValueError(f"F must have shape (m,{V.shape[-1] + 1}) for V of shape {V.shape}, got {F.shape}")
    if F.size and (F.dtype == bool or not np.issubdtype(F.dtype, np.integer)):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        t, j = (int(x) for x in np.argwhere((F < 0) | (F >= len(V)))[0])
        raise ValueError(
            f"element {t} of F indexes vertex {F[t, j].item()!r}, but V has {len(V)} vertices "
            f"(valid indices 0 to {len(V) - 1})"
        )
    P = V[F]
    return simplex_volumes(P[:, 0], P[:, 1:])


#: the planar name of :func:`signed_volumes` (triangles: signed areas)
signed_areas = signed_volumes


#: a mesh whose bounding-box diagonal lies outside this range has its Laplacian computed on a copy scaled by a power
#: of 4 into it: libigl's tetrahedral cotangent weights underflow to NaN at 1e-30 and to 0 from about 1e27
SAFE_DIAGONAL = (2.0**-20, 2.0**20)


def cotangent_laplacian(V, F):
    """(n, n) scipy sparse CSR: the cotangent Laplacian (libigl's ``cotmatrix``), exact at any supported scale.

    It scales as length^(d-2); outside :data:`SAFE_DIAGONAL` it is computed on ``V / 4^k`` and multiplied by
    ``4^(k(d-2))``: exact powers of two, so inside the range nothing changes (bit for bit).
    """
    diag = bbox_diagonal(V)
    k = 0 if diag == 0 or SAFE_DIAGONAL[0] <= diag <= SAFE_DIAGONAL[1] else int(round(np.log2(diag) / 2))
    if k == 0:
        return igl.cotmatrix(V, F).tocsr()
    s = 4.0**k
    return (igl.cotmatrix(V / s, F) * s ** (V.shape[1] - 2)).tocsr()


def element_facets(F):
    """All facets of the elements, outward-oriented: (m(d+1), d) and the element of each."""
    d = F.shape[1] - 1
    facets = np.concatenate([F[:, f] for f in FACETS[d]])
    return facets, np.tile(np.arange(len(F)), d + 1)


def boundary_facets(F):
    """(k, d) int numpy array: the facets of the elements F (m, d + 1) that lie in one element only,
    outward-oriented (edges of triangles, triangles of tetrahedra)."""
    facets, _ = element_facets(F)
    _, inv, counts = np.unique(np.sort(facets, axis=1), axis=0, return_inverse=True, return_counts=True)
    return np.ascontiguousarray(facets[counts[inv.ravel()] == 1])


def degenerate_scale(V, d):
    """The volume below which an element counts as degenerate: 1e-14 × (largest extent)^d."""
    return max(np.ptp(V, axis=0).max(), 1e-300) ** d
