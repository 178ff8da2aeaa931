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
from scipy.spatial import cKDTree

from .mesh_checks import (
    check_closed_surface,
    check_elements,
    check_tet_manifold,
    check_triangle_manifold,
    check_vertices,
    dim_of,
    orient_elements,
)
from .mesh_text import igl_write as _igl_write
from .mesh_text import read_text_mesh as _read_text
from .simplices import (
    ELEMENT,
    ELEMENTS,
    FACETS,
    boundary_facets,
    cotangent_laplacian,
    degenerate_scale,
    signed_areas,
    signed_volumes,
    simplex_volumes,
)
from .simplices import SAFE_DIAGONAL as SAFE_DIAGONAL  # re-exported
from .surface_files import MAX_FILE_ELEMENTS, check_file

__all__ = [
    "Mesh",
    "element_dof_pattern",
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
        d = dim_of(V, F)
        V_cols = np.shape(V)[1] if np.ndim(V) == 2 else None
        note = f" for F of {d + 1} columns ({ELEMENTS[d]})" if d == 3 else ""
        if d == 2 and V_cols == 3:
            note = " for triangles F (m,3); a 3D mesh is made of tetrahedra, F (m,4)"
        V = check_vertices(V, d=d, F_note=note)
        F = check_elements(F, len(V), d)
        a = signed_volumes(V, F)
        tiny = np.abs(a) <= 1e-14 * degenerate_scale(V, d)
        if tiny.any():
            first = int(np.flatnonzero(tiny)[0])
            what = "zero-area" if d == 2 else "zero-volume"
            raise ValueError(
                f"{int(tiny.sum())} degenerate ({what}) {ELEMENTS[d]}, first is {ELEMENT[d]} {first}"
                + ("" if d == 2 else f" (volume {a[first]:.3g})")
            )
        F = orient_elements(F, a)
        if d == 2:
            check_triangle_manifold(F)
        else:
            check_tet_manifold(F)
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

    _NOT_PICKLED = ("dof_pairs", "bilaplacian", "_kdtree")  # rebuilt on demand; joblib sends the mesh with every task

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._NOT_PICKLED}

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

    @cached_property
    def bilaplacian(self):
        """(n,n) scipy sparse CSC: the bi-Laplacian L M⁻¹ L, factorised on its free vertices by every handle set."""
        return (self.cotmatrix.T @ sp.diags(1.0 / self.mass_matrix.diagonal()) @ self.cotmatrix).tocsc()

    @cached_property
    def dof_pairs(self):
        """(dofs, pairs, inverse): :func:`element_dof_pattern` of this mesh, once per mesh."""
        return element_dof_pattern(self.F, self.n_vertices)

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
        points = check_vertices(np.atleast_2d(points), "points", d=self.dim)
        dist, idx = self._kdtree.query(points)
        return np.asarray(idx, dtype=np.int64), np.asarray(dist)

    def contains(self, points):
        """(k,) bool array: whether each point lies in Ω (inside some element, with a 1e-12 tolerance)."""
        points = check_vertices(np.atleast_2d(points), "points", d=self.dim)
        P = self.V[self.F]  # (m, d+1, d)
        facets = FACETS[self.dim]
        eps = -0.5e-12 * self.bbox_diagonal**self.dim
        out = np.zeros(len(points), dtype=bool)
        for k, p in enumerate(points):  # p inside iff every simplex (p, facet) is positive
            p0 = np.broadcast_to(p, (len(P), self.dim))
            inside = np.ones(len(P), dtype=bool)
            for f in facets:
                inside &= simplex_volumes(p0, P[:, f]) >= eps
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
        points = check_vertices(np.atleast_2d(points), "points", d=self.dim)
        k = min(k, self.n_faces)
        _, cand = self._centroid_tree.query(points, k=k)
        cand = np.asarray(cand).reshape(len(points), k)
        P = self.V[self.F[cand.ravel()]]  # (p*k, d+1, d)
        p0 = np.repeat(points, k, axis=0)
        lam = np.stack([simplex_volumes(p0, P[:, f]) for f in FACETS[self.dim]], axis=1)
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
        if "header.npy" in z.names():  # what every operator file holds and a mesh file never does
            raise ValueError(
                f"mesh file {path} is a defop operator file, not a mesh file: load it with DefOp.load, "
                "MovableOp.load or BranchedOperator.load (its mesh is the operator's .mesh)"
            )
        if not {"V.npy", "F.npy"} <= set(z.names()):
            raise ValueError(f"mesh file {path} holds no mesh (arrays V and F are missing)")
        members = z.members(check=check)
        return z.read(members["V"]), z.read(members["F"])


def element_dof_pattern(F, n_vertices):
    """The sparsity pattern of every matrix assembled element by element over the vertex dofs d·v + c of the elements
    ``F`` (m, d + 1) over ``n_vertices`` vertices (d read from ``F``): the Hessian of problem (6) before any handle is
    eliminated. :attr:`Mesh.dof_pairs` keeps it per mesh; a handle set's pattern is the part of it on its free dofs
    (:class:`defop.variational.problem.ReducedHessian`).

    Returns
    -------
    dofs : (m, k) int64 numpy array
        Each element's dofs in local order (k = (d + 1)·d: local dof d·i + c is d·F[t, i] + c).
    pairs : (p,) int64 numpy array
        The distinct dof pairs (row, col) that share an element with row <= col, as col·N + row (N = d·n),
        sorted: column-major, CSC order.
    inverse : (m·k²,) int64 numpy array
        Per local entry t·k² + i·k + j (row dofs[t, i], col dofs[t, j]) its index in ``pairs``, −1 below the
        diagonal.
    """
    d = F.shape[1] - 1
    k = F.shape[1] * d
    dofs = (d * F[:, :, None] + np.arange(d)).reshape(len(F), -1).astype(np.int64)
    rows, cols = np.repeat(dofs, k, axis=1).ravel(), np.tile(dofs, (1, k)).ravel()
    upper = np.flatnonzero(rows <= cols)
    pairs, inv = np.unique(cols[upper] * (d * n_vertices) + rows[upper], return_inverse=True)
    inverse = -np.ones(len(rows), np.int64)
    inverse[upper] = inv.ravel()
    return dofs, pairs, inverse
