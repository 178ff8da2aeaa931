"""Simplicial meshes of a domain Ω ⊂ R^d (d = 2 or 3) and the operators the paper builds on them.

A :class:`Mesh` holds ``V (n, d)`` and ``F (m, d + 1)``: counter-clockwise triangles in 2D,
positively oriented tetrahedra in 3D; ``mesh.dim`` is d, read from the data. It supplies what
problem (6) and problem (8) need: element volumes (areas in 2D), the per-element Jacobian J
(d × d) of a piecewise-linear map ``X (n, d)`` (the deformation gradient of f_Φ, Eq. 1), the mass
matrix A (Appendix A) and the cotangent Laplacian. One code path serves both dimensions; only the
determinant and the element's facets are written per dimension.
"""

from __future__ import annotations

import io
import os
from functools import cached_property
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .surface_files import MAX_FILE_ELEMENTS, bbox_diagonal, check_file, check_size, parse_surface

__all__ = [
    "Mesh",
    "read_mesh",
    "write_mesh",
    "signed_volumes",
    "signed_areas",
    "cotangent_laplacian",
    "boundary_facets",
    "check_closed_surface",
    "ELEMENT",
    "FACETS",
]

#: the name of an element of a d-dimensional mesh
ELEMENT = {2: "triangle", 3: "tetrahedron"}
_ELEMENTS = {2: "triangles", 3: "tetrahedra"}

#: facet j of an element is the one opposite its vertex j, ordered so that it faces outward:
#: for a positive element, the simplex ``(p, *facet)`` is positive exactly when p is on the element's side
FACETS = {
    2: np.array([[1, 2], [2, 0], [0, 1]]),
    3: np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]),
}


def _simplex_volumes(P0, P):
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
    return _simplex_volumes(P[:, 0], P[:, 1:])


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


def _dim_of(V, F):
    """d from F's columns (3: triangles, 4: tetrahedra), else from V; V's columns must agree."""
    F_ = np.asarray(F)
    if F_.ndim == 2 and F_.shape[1] in (3, 4):
        return F_.shape[1] - 1
    V_ = np.asarray(V)
    return V_.shape[1] if V_.ndim == 2 and V_.shape[1] in (2, 3) else 2


def _check_V(V, name="V", d=2, F_note=""):
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != d:
        raise ValueError(f"{name} must have shape (n,{d}){F_note}, got {V.shape}")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ValueError(
            f"{name} has {int(bad.sum())} non-finite (NaN or inf) rows, first at row {int(np.flatnonzero(bad)[0])}"
        )
    return V


def _check_F(F, n, d=2):
    """F as an (m, d + 1) int64 array of indices into n vertices; ValueError naming the bad entry."""
    F = np.asarray(F)
    el, els = ELEMENT[d], _ELEMENTS[d]
    if F.ndim != 2 or F.shape[1] != d + 1:
        raise ValueError(f"F must have shape (m,{d + 1}), got {F.shape}")
    if len(F) == 0:
        raise ValueError(f"F has no {els}")
    if F.dtype == bool or not (np.issubdtype(F.dtype, np.integer) or np.issubdtype(F.dtype, np.floating)):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    if not np.issubdtype(F.dtype, np.integer):
        bad = ~np.isfinite(F) | (F != np.round(F))
        if bad.any():
            t, j = (int(x) for x in np.argwhere(bad)[0])
            raise ValueError(f"F must hold integer vertex indices: {el} {t} has {F[t, j].item()!r}")
    bad = (F < 0) | (F >= n)
    if bad.any():
        t, j = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(
            f"{el} {t} indexes vertex {F[t, j].item()!r}, but V has {n} vertices (valid indices 0 to {n - 1})"
        )
    return F.astype(np.int64)


def _orient(F, a):
    """F positively oriented: all-negative input is flipped; a mix means inverted elements."""
    cw = a < 0
    if cw.all():
        return np.ascontiguousarray(F[:, [0, 2, 1, *range(3, F.shape[1])]])
    if cw.any():
        t = int(np.flatnonzero(cw)[0])
        if F.shape[1] == 3:
            raise ValueError(
                f"triangle {t} is inverted (clockwise, signed area {a[t]:.3g}) while {int((~cw).sum())} triangles "
                f"are counter-clockwise ({int(cw.sum())} inverted in all): the mesh folds over itself"
            )
        raise ValueError(
            f"tetrahedron {t} is inverted (signed volume {a[t]:.3g}) while {int((~cw).sum())} tetrahedra are "
            f"positively oriented ({int(cw.sum())} inverted in all): the mesh folds over itself"
        )
    return F


def _facets(F):
    """All facets of the elements, outward-oriented: (m(d+1), d) and the element of each."""
    d = F.shape[1] - 1
    facets = np.concatenate([F[:, f] for f in FACETS[d]])
    return facets, np.tile(np.arange(len(F)), d + 1)


def boundary_facets(F):
    """(k, d) int numpy array: the facets of the elements F (m, d + 1) that lie in one element only,
    outward-oriented (edges of triangles, triangles of tetrahedra)."""
    facets, _ = _facets(F)
    _, inv, counts = np.unique(np.sort(facets, axis=1), axis=0, return_inverse=True, return_counts=True)
    return np.ascontiguousarray(facets[counts[inv.ravel()] == 1])


def _check_manifold(F):
    """Every edge in at most two triangles, an interior edge used once in each direction, one fan per vertex."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    tri = np.tile(np.arange(len(F)), 3)
    key = np.sort(E, axis=1)
    uniq, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts > 2).any():
        k = int(np.flatnonzero(counts > 2)[0])
        ts = np.sort(tri[inv == k])
        raise ValueError(
            f"edge ({int(uniq[k, 0])}, {int(uniq[k, 1])}) is shared by {int(counts[k])} triangles "
            f"({', '.join(map(str, ts))}): the mesh is not a manifold"
        )
    boundary = uniq[counts == 1]
    per_vertex = np.bincount(boundary.ravel(), minlength=int(F.max()) + 1)
    if (per_vertex > 2).any():
        v = int(np.flatnonzero(per_vertex > 2)[0])
        raise ValueError(
            f"vertex {v} is not a manifold vertex: {int(per_vertex[v])} boundary edges meet there (its triangles "
            "form separate fans, as where two pieces touch at a corner)"
        )
    d_uniq, d_counts = np.unique(E, axis=0, return_counts=True)
    if (d_counts > 1).any():
        k = int(np.flatnonzero(d_counts > 1)[0])
        i, j = (int(x) for x in d_uniq[k])
        ts = np.sort(tri[(E[:, 0] == i) & (E[:, 1] == j)])
        raise ValueError(
            f"edge ({i}, {j}) is used in the same direction by triangles {', '.join(map(str, ts))}: "
            "their orientations disagree (the mesh folds over itself)"
        )


def _check_manifold_tets(T):
    """Every triangle in at most two tetrahedra, from opposite sides; the boundary a closed manifold surface."""
    facets, tet = _facets(T)
    uniq, inv, counts = np.unique(np.sort(facets, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts > 2).any():
        k = int(np.flatnonzero(counts > 2)[0])
        raise ValueError(
            f"triangle {tuple(int(x) for x in uniq[k])} is shared by {int(counts[k])} tetrahedra "
            f"({', '.join(map(str, np.sort(tet[inv == k])))}): the mesh is not a manifold"
        )
    shared = np.flatnonzero(counts[inv] == 2)
    if len(shared):  # two tetrahedra on the same side of their common triangle overlap
        order = np.argsort(inv[shared], kind="stable")
        a, b = shared[order[0::2]], shared[order[1::2]]
        same = _same_cyclic(facets[a], facets[b])
        if same.any():
            k = int(np.flatnonzero(same)[0])
            raise ValueError(
                f"tetrahedra {min(tet[a[k]], tet[b[k]])} and {max(tet[a[k]], tet[b[k]])} lie on the same side of "
                f"their common triangle {tuple(int(x) for x in np.sort(facets[a[k]]))}: the mesh folds over itself"
            )
    check_closed_surface(facets[counts[inv] == 1], what="the boundary surface of the tetrahedra")


def _same_cyclic(A, B):
    """(k,) bool: whether triangles A[i] and B[i] (same vertex set) have the same orientation."""
    return (A == B).all(axis=1) | (A == B[:, [1, 2, 0]]).all(axis=1) | (A == B[:, [2, 0, 1]]).all(axis=1)


def check_closed_surface(S, what="the surface"):
    """Raise ValueError unless the triangles S (k, 3) form a closed, oriented 2-manifold.

    Every edge lies in exactly two triangles that traverse it in opposite directions, and the
    triangles around each vertex form a single fan (no two pieces touching at a vertex).

    Parameters
    ----------
    S : (k, 3) int numpy array
        Triangles (indices into some vertex array).
    what : str
        How the message names the surface.
    """
    S = np.asarray(S, dtype=np.int64)
    E = np.concatenate([S[:, [0, 1]], S[:, [1, 2]], S[:, [2, 0]]])
    uniq, inv, counts = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts != 2).any():
        k = int(np.flatnonzero(counts != 2)[0])
        e, c = (int(uniq[k, 0]), int(uniq[k, 1])), int(counts[k])
        kind = (
            f"open: edge {e} lies in only 1 triangle" if c == 1 else f"not a manifold: edge {e} lies in {c} triangles"
        )
        ts = np.sort(np.tile(np.arange(len(S)), 3)[inv == k])
        raise ValueError(f"{what} is {kind} ({', '.join(map(str, ts))})")
    d_uniq, d_counts = np.unique(E, axis=0, return_counts=True)
    if (d_counts > 1).any():
        i, j = (int(x) for x in d_uniq[int(np.flatnonzero(d_counts > 1)[0])])
        raise ValueError(
            f"{what} is not consistently oriented: edge ({i}, {j}) is traversed in the same direction by two "
            "triangles (a flipped triangle or a Möbius-like fold)"
        )
    _check_single_fans(S, E, inv)


def _check_single_fans(S, E, inv):
    """Each vertex's triangles form one fan: corners (t, v) linked across the edges at v are one component."""
    k = len(S)
    order = np.argsort(inv, kind="stable")
    a, b = order[0::2], order[1::2]  # the two half-edges of every edge; half-edge h belongs to triangle h % k
    ta, tb = a % k, b % k
    # half-edge h = block*k + t runs S[t, block] -> S[t, (block+1)%3]; its ends are corners (t, block), (t, block+1)
    ja, jb = a // k, b // k
    # edge (u -> w) in triangle ta and (w -> u) in tb: corner (ta, u) ~ (tb, u), corner (ta, w) ~ (tb, w)
    src = np.concatenate([3 * ta + ja, 3 * ta + (ja + 1) % 3])
    dst = np.concatenate([3 * tb + (jb + 1) % 3, 3 * tb + jb])
    G = sp.coo_matrix((np.ones(len(src)), (src, dst)), shape=(3 * k, 3 * k))
    _, label = connected_components(G, directed=False)
    vertex = S.ravel()  # corner 3t + j is vertex S[t, j]
    pairs = np.unique(np.column_stack([vertex, label]), axis=0)
    fans = np.bincount(pairs[:, 0])
    if (fans > 1).any():
        v = int(np.flatnonzero(fans > 1)[0])
        raise ValueError(
            f"vertex {v} is not a manifold vertex: its triangles form {int(fans[v])} separate fans on the boundary "
            "surface (as where two pieces touch at a corner)"
        )


def _degenerate_scale(V, d):
    """The volume below which an element counts as degenerate: 1e-14 × (largest extent)^d."""
    return max(np.ptp(V, axis=0).max(), 1e-300) ** d


class Mesh:
    """A simplicial mesh of a domain Ω ⊂ R^d: triangles in 2D, tetrahedra in 3D.

    Parameters
    ----------
    V : (n, d) numpy array
        Vertex positions (float64), d = 2 or 3.
    F : (m, d + 1) numpy int array
        Triangles (d = 2), all counter-clockwise or all clockwise, or tetrahedra (d = 3), all
        positively or all negatively oriented; an all-negative mesh is re-oriented.

    Raises
    ------
    ValueError
        For wrong shapes, non-finite coordinates, out-of-range indices, degenerate (zero-volume)
        elements, inverted elements (a mesh that folds over itself; the message names the first
        and its signed volume), a facet shared by more than two elements, a boundary that is not
        a manifold (in 3D: not a closed, oriented, manifold triangle surface), or vertices no
        element uses; the message names the element, edge, triangle or vertex.
    """

    def __init__(self, V, F):
        d = _dim_of(V, F)
        V_cols = np.shape(V)[1] if np.ndim(V) == 2 else None
        note = f" for F of {d + 1} columns ({_ELEMENTS[d]})" if d == 3 else ""
        if d == 2 and V_cols == 3:
            note = " for triangles F (m,3); a 3D mesh is made of tetrahedra, F (m,4)"
        V = _check_V(V, d=d, F_note=note)
        F = _check_F(F, len(V), d)
        a = signed_volumes(V, F)
        tiny = np.abs(a) <= 1e-14 * _degenerate_scale(V, d)
        if tiny.any():
            first = int(np.flatnonzero(tiny)[0])
            what = "zero-area" if d == 2 else "zero-volume"
            raise ValueError(
                f"{int(tiny.sum())} degenerate ({what}) {_ELEMENTS[d]}, first is {ELEMENT[d]} {first}"
                + ("" if d == 2 else f" (volume {a[first]:.3g})")
            )
        F = _orient(F, a)
        if d == 2:
            _check_manifold(F)
        else:
            _check_manifold_tets(F)
        unused = np.flatnonzero(np.bincount(F.ravel(), minlength=len(V)) == 0)
        if len(unused):
            raise ValueError(
                f"{len(unused)} vertices are not used by any {ELEMENT[d]}, first is vertex {int(unused[0])}; "
                "remove them (handle indices refer to rows of V)"
            )
        self.V = np.ascontiguousarray(V)
        self.F = np.ascontiguousarray(F)

    # ------------------------------------------------------------------ sizes
    @property
    def dim(self) -> int:
        """d: 2 for a triangle mesh, 3 for a tetrahedral mesh."""
        return self.V.shape[1]

    @property
    def n_vertices(self) -> int:
        return len(self.V)

    @property
    def n_faces(self) -> int:
        """Number of elements (rows of F): triangles in 2D, tetrahedra in 3D."""
        return len(self.F)

    def __repr__(self):
        if self.dim == 2:
            return f"Mesh(n_vertices={self.n_vertices}, n_faces={self.n_faces})"
        return f"Mesh(n_vertices={self.n_vertices}, n_tets={self.n_faces}, dim=3)"

    @cached_property
    def volumes(self):
        """(m,) numpy array: rest volume of every element (area A_t of a triangle in 2D)."""
        return signed_volumes(self.V, self.F)

    @property
    def areas(self):
        """(m,) numpy array: the planar name of :attr:`volumes` (in 3D, tetrahedron volumes)."""
        return self.volumes

    @cached_property
    def bbox_diagonal(self) -> float:
        """Length of the bounding-box diagonal."""
        ext = np.ptp(self.V, axis=0)
        s = ext[0] * ext[0]
        for k in range(1, self.dim):
            s = s + ext[k] * ext[k]
        return float(np.sqrt(s))  # element-wise: the same on every BLAS

    # ------------------------------------------------------------- boundary
    @cached_property
    def boundary_facets(self):
        """(k, d) int numpy array: the boundary, outward-oriented.

        Edges in 2D (counter-clockwise around Ω: the interior on their left), triangles in 3D
        (the closed boundary surface; normals by the right-hand rule point out of Ω).
        """
        return boundary_facets(self.F)

    @cached_property
    def boundary_vertices(self):
        """(b,) int numpy array: the vertices on the boundary, sorted."""
        return np.unique(self.boundary_facets)

    def boundary_loops(self):
        """Boundary loops of a 2D mesh, outer loop first (longest), each a (k,) int array."""
        if self.dim != 2:
            raise ValueError("boundary_loops is for 2D meshes; a 3D mesh's boundary is boundary_facets (triangles)")
        loops = igl.boundary_loop_all(self.F) if hasattr(igl, "boundary_loop_all") else [igl.boundary_loop(self.F)]
        loops = [np.asarray(loop, dtype=np.int64) for loop in loops]
        return sorted(loops, key=lambda loop: -len(loop))

    # ------------------------------------------------------------ Jacobians
    @cached_property
    def local_gradients(self):
        """(m, d + 1, d) numpy array: ∇φ_i of the d + 1 hat functions on every element.

        For a piecewise-linear map with vertex positions X, the Jacobian on element t is
        ``J_t = X[F[t]].T @ local_gradients[t]`` (d × d).
        """
        P = self.V[self.F]  # (m, d+1, d)
        E = np.stack([P[:, i] - P[:, 0] for i in range(1, self.dim + 1)], axis=2)  # (m,d,d) columns e_i
        g = np.linalg.inv(E)  # (m,d,d): row i = grad of barycentric λ_{i+1}
        g0 = -g.sum(axis=1, keepdims=True)
        return np.ascontiguousarray(np.concatenate([g0, g], axis=1))

    def jacobians(self, X):
        """Per-element Jacobians of the piecewise-linear map X.

        Parameters
        ----------
        X : (n, d) numpy array
            Deformed vertex positions.

        Returns
        -------
        J : (m, d, d) numpy array
            ``J[t, a, b] = ∂X_a/∂x_b`` on element t.
        """
        X = np.asarray(X, dtype=float)
        if X.shape != self.V.shape:
            raise ValueError(f"X must have shape {self.V.shape}, got {X.shape}")
        d = self.dim
        return (self.jacobian_operator @ X.ravel()).reshape(-1, d, d)  # sparse: 15x faster than einsum

    @cached_property
    def jacobian_operator(self):
        """Sparse (d²m, dn) operator G with ``G @ X.ravel() == jacobians(X).reshape(-1)``.

        ``X.ravel()`` is row-major (x0, y0, [z0,] x1, ...); each block of d² rows is J of one
        element, row-major (J00, J01, ..., J10, ...).
        """
        m, d = self.n_faces, self.dim
        D = self.local_gradients  # (m, d+1, d)
        t = np.arange(m)
        rows, cols, vals = [], [], []
        for a in range(d):
            for b in range(d):
                for i in range(d + 1):
                    rows.append(d * d * t + d * a + b)
                    cols.append(d * self.F[:, i] + a)
                    vals.append(D[:, i, b])
        return sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(d * d * m, d * self.n_vertices),
        )

    def flipped(self, X):
        """(m,) bool array: elements whose orientation X reverses or collapses (det J ≤ 0)."""
        return signed_volumes(X, self.F) <= 0

    # ------------------------------------------------------- FEM matrices
    @cached_property
    def mass_matrix(self):
        """(n,n) scipy sparse: lumped mass matrix A of the hat functions (libigl).

        Voronoi areas in 2D; in 3D a quarter of each tetrahedron's volume to each of its vertices
        (barycentric lumping: positive for every tetrahedron, where libigl's Voronoi variant is not).
        """
        kind = igl.MASSMATRIX_TYPE_VORONOI if self.dim == 2 else igl.MASSMATRIX_TYPE_BARYCENTRIC
        return igl.massmatrix(self.V, self.F, kind).tocsr()

    @cached_property
    def mass_matrix_full(self):
        """(n,n) scipy sparse: consistent (full) FEM mass matrix, A_ii' = ∫ φ_i φ_i' (libigl)."""
        return igl.massmatrix(self.V, self.F, igl.MASSMATRIX_TYPE_FULL).tocsr()

    @cached_property
    def cotmatrix(self):
        """(n,n) scipy sparse: cotangent Laplacian L (negative semi-definite, libigl; cotangent weights of
        dihedral angles times edge lengths on tetrahedra)."""
        return cotangent_laplacian(self.V, self.F)

    # -------------------------------------------------------------- lookup
    @cached_property
    def _kdtree(self):
        return cKDTree(self.V)

    def nearest_vertex(self, points):
        """Nearest mesh vertex of each point.

        Parameters
        ----------
        points : (k, d) numpy array

        Returns
        -------
        idx : (k,) int array
        dist : (k,) numpy array
        """
        points = _check_V(np.atleast_2d(points), "points", d=self.dim)
        dist, idx = self._kdtree.query(points)
        return np.asarray(idx, dtype=np.int64), np.asarray(dist)

    def contains(self, points):
        """(k,) bool array: whether each point lies in Ω (inside some element, with a 1e-12 tolerance)."""
        points = _check_V(np.atleast_2d(points), "points", d=self.dim)
        P = self.V[self.F]  # (m, d+1, d)
        facets = FACETS[self.dim]
        eps = -0.5e-12 * self.bbox_diagonal**self.dim
        out = np.zeros(len(points), dtype=bool)
        for k, p in enumerate(points):  # p inside iff every simplex (p, facet) is positive
            p0 = np.broadcast_to(p, (len(P), self.dim))
            inside = np.ones(len(P), dtype=bool)
            for f in facets:
                inside &= _simplex_volumes(p0, P[:, f]) >= eps
            out[k] = bool(inside.any())
        return out

    @cached_property
    def _centroid_tree(self):
        P = self.V[self.F]
        return cKDTree(P.sum(axis=1) / (self.dim + 1))

    def locate(self, points, k=16):
        """The element holding each point and the point's barycentric coordinates in it.

        Used to embed a fine surface in a coarser tetrahedral mesh: the embedded points follow a
        deformation X as ``(bary[:, :, None] * X[mesh.F[elements]]).sum(1)``.

        Parameters
        ----------
        points : (p, d) numpy array
        k : int
            How many elements (nearest centroids) are tried per point.

        Returns
        -------
        elements : (p,) int numpy array
        bary : (p, d + 1) numpy array
            Barycentric coordinates (rows sum to 1, all ≥ 0 inside the element). A point outside the
            mesh gets the candidate element where it is least outside (some coordinates negative).
        """
        points = _check_V(np.atleast_2d(points), "points", d=self.dim)
        k = min(k, self.n_faces)
        _, cand = self._centroid_tree.query(points, k=k)
        cand = np.asarray(cand).reshape(len(points), k)
        P = self.V[self.F[cand.ravel()]]  # (p*k, d+1, d)
        p0 = np.repeat(points, k, axis=0)
        lam = np.stack([_simplex_volumes(p0, P[:, f]) for f in FACETS[self.dim]], axis=1)
        lam = lam / self.volumes[cand.ravel()][:, None]
        lam = lam.reshape(len(points), k, self.dim + 1)
        best = np.argmax(lam.min(axis=2), axis=1)
        rows = np.arange(len(points))
        return cand[rows, best].astype(np.int64), lam[rows, best]

    # ----------------------------------------------------------------- I/O
    def save(self, path):
        """Write to ``.npz``, ``.obj`` or ``.off`` (see :func:`write_mesh`)."""
        write_mesh(path, self)

    @classmethod
    def load(cls, path):
        """Read from ``.npz``, ``.obj`` or ``.off`` (see :func:`read_mesh`)."""
        return read_mesh(path)

    def __eq__(self, other):
        if not isinstance(other, Mesh):
            return NotImplemented
        return np.array_equal(self.V, other.V) and np.array_equal(self.F, other.F)

    __hash__ = None


def write_mesh(path, mesh):
    """Write a mesh, atomically (a temporary file in the same directory, then a rename).

    ``.npz`` is exact. ``.obj``/``.off`` go through libigl with z = 0 and
    17 significant digits, so the round trip is exact for float64 too.

    Raises
    ------
    ValueError
        ``mesh`` is not a :class:`Mesh`, or an unknown extension (nothing is written).
    OSError
        The file cannot be written (the message names it; a previous file is left as it was).
    """
    from .. import options as opt

    if not isinstance(mesh, Mesh):
        raise ValueError(f"mesh must be a defop Mesh, got {type(mesh).__name__}")
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or pathlib.Path, got {type(path).__name__}")
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".npz":
        buf = io.BytesIO()  # np.savez(path) would append ".npz" to "m.NPZ"
        np.savez(buf, V=mesh.V, F=mesh.F)
        opt.write_atomic(path, buf.getvalue())
    elif ext in (".obj", ".off") and mesh.dim == 3:
        raise ValueError(f"a tetrahedral mesh is written as .npz ({ext} holds triangle surfaces)")
    elif ext in (".obj", ".off"):
        V3 = np.hstack([mesh.V, np.zeros((mesh.n_vertices, 1))])
        F = mesh.F.astype(np.int64)
        opt.write_atomic(path, lambda tmp: _igl_write(tmp, V3, F))
    else:
        raise ValueError(f"unknown mesh format {ext!r}; use .npz, .obj or .off")


def read_mesh(path):
    """Read a mesh written by :func:`write_mesh` (or any planar OBJ/OFF).

    Untrusted files are checked before work: the sizes an ``.npz`` member or an OFF header declares
    (at most :data:`MAX_FILE_ELEMENTS` rows, and no more than the file can hold), the archive's layout, no
    pickles; every error names the file.

    Raises
    ------
    ValueError
        A missing, truncated or corrupt file, one that is not a mesh, declares too many elements, or holds an
        invalid mesh (the message names the file and what is wrong).
    """
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or pathlib.Path, got {type(path).__name__}")
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in (".npz", ".obj", ".off"):
        raise ValueError(f"mesh file {path}: unknown mesh format {ext!r}; use .npz, .obj or .off")
    path = check_file(path, "mesh file")  # missing, a directory, a FIFO, no read permission: each said so
    V, F = _read_npz(path) if ext == ".npz" else _read_text(path, ext)
    try:
        return Mesh(V, F)
    except ValueError as exc:
        raise ValueError(f"mesh file {path} holds an invalid mesh: {exc}") from None


def _read_npz(path):
    """V and F of an .npz by the one archive reader (:class:`defop.geometry.archive.NpzReader`): each member's
    header checked (numbers, the shape, :data:`MAX_FILE_ELEMENTS` rows) before its data is inflated."""
    import zipfile

    from .archive import ArchiveError, Limits, NpzReader

    if not zipfile.is_zipfile(path):
        raise ValueError(f"mesh file {path} is not an .npz archive (not a zip file: truncated, or another format)")
    label = f"mesh file {path}"

    def check(key, shape, dtype):
        cols = {"V": (2, 3), "F": (3, 4)}.get(key)  # Mesh itself checks that they fit together
        if cols is None:
            return
        if len(shape) != 2 or shape[1] not in cols:
            raise ArchiveError(f"{label}: {key} must be an (n, {' or '.join(map(str, cols))}) array, got shape {shape}")
        if shape[0] > MAX_FILE_ELEMENTS:
            raise ArchiveError(
                f"{label} declares {shape[0]:,} rows of {key}, limit {MAX_FILE_ELEMENTS:,} "
                f"(defop.geometry.mesh.MAX_FILE_ELEMENTS)"
            )

    limits = Limits(max_members=64, kinds="iuf", exact_size=False)  # reads stop at the declared size
    with NpzReader(path, label, "an .npz archive", limits) as z:
        if not {"V.npy", "F.npy"} <= set(z.names()):
            raise ValueError(f"mesh file {path} holds no mesh (arrays V and F are missing)")
        members = z.members(check=check)
        return z.read(members["V"]), z.read(members["F"])


def _read_text(path, ext):
    """V and F of an OBJ/OFF (numpy reader, :mod:`.surface_files`), the OFF header's counts checked first."""
    size = check_size(path, "mesh file")  # read whole below: a 3 GiB file raised an empty MemoryError
    if ext == ".off":
        _check_off_header(path, size)
    try:
        V, F, _ = parse_surface(path.read_bytes(), ext)
    except ValueError as exc:
        raise ValueError(f"mesh file {path} could not be read as {ext} ({exc})") from None
    if V.shape[1] == 3:
        if np.abs(V[:, 2]).max(initial=0) > 0:
            raise ValueError(f"{path} is not planar (z is not 0)")
        V = V[:, :2]
    return V, F


def _check_off_header(path, size):
    with open(path, "rb") as fh:
        head = fh.read(4096).decode("ascii", "replace").split("\n")
    words = []
    for line in head:
        words += line.split("#")[0].split()
        if len(words) >= 4:
            break
    if not words or not words[0].upper().endswith("OFF"):
        raise ValueError(f"mesh file {path} is not an OFF file (no OFF header)")
    try:
        n_v, n_f = int(words[1]), int(words[2])
    except (IndexError, ValueError):
        raise ValueError(f"mesh file {path}: the OFF header has no vertex and face counts") from None
    if min(n_v, n_f) < 0 or max(n_v, n_f) > MAX_FILE_ELEMENTS or 2 * (n_v + n_f) > size:
        raise ValueError(
            f"mesh file {path} declares {n_v:,} vertices and {n_f:,} faces in {size:,} bytes "
            f"(limit {MAX_FILE_ELEMENTS:,} each, and at least 2 bytes per entry)"
        )


def _igl_write(path, V3, F):
    igl.write_triangle_mesh(str(path), V3, F, igl.FileEncoding.Ascii)
