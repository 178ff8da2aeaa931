"""Triangle meshes of a planar domain Ω and the operators the paper builds on them.

A :class:`Mesh` holds ``V (n,2)`` and ``F (m,3)`` with counter-clockwise triangles.
It supplies what problem (6) and problem (8) need: triangle areas, the per-triangle
Jacobian J of a piecewise-linear map ``X (n,2)`` (the deformation gradient of
f_Φ, Eq. 1), the mass matrix A (Appendix A) and the cotangent Laplacian.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["Mesh", "read_mesh", "write_mesh", "signed_areas"]


def signed_areas(V, F):
    """Signed area of every triangle.

    Parameters
    ----------
    V : (n,2) numpy array
        Vertex positions.
    F : (m,3) numpy int array
        Triangles.

    Returns
    -------
    a : (m,) numpy array
        Positive for counter-clockwise triangles, negative for flipped ones.
    """
    V = np.asarray(V, dtype=float)
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _check_V(V, name="V"):
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n,2), got {V.shape}")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ValueError(
            f"{name} has {int(bad.sum())} non-finite (NaN or inf) rows, first at row {int(np.flatnonzero(bad)[0])}"
        )
    return V


class Mesh:
    """A triangulated planar domain Ω.

    Parameters
    ----------
    V : (n,2) numpy array
        Vertex positions (float64).
    F : (m,3) numpy int array
        Triangles. Clockwise triangles are re-oriented counter-clockwise.

    Raises
    ------
    ValueError
        For wrong shapes, non-finite coordinates, out-of-range indices or
        degenerate (zero-area) triangles.
    """

    def __init__(self, V, F):
        V = _check_V(V)
        F = np.asarray(F)
        if F.ndim != 2 or F.shape[1] != 3:
            raise ValueError(f"F must have shape (m,3), got {F.shape}")
        if len(F) == 0:
            raise ValueError("F has no triangles")
        if not np.issubdtype(F.dtype, np.integer):
            if not np.all(F == np.round(F)):
                raise ValueError("F must hold integer vertex indices")
        F = F.astype(np.int64)
        if F.min() < 0 or F.max() >= len(V):
            raise ValueError(f"F indexes vertex {int(F.max())} but V has only {len(V)} vertices")
        a = signed_areas(V, F)
        F = np.where((a < 0)[:, None], F[:, [0, 2, 1]], F)
        a = np.abs(a)
        scale = max(np.ptp(V, axis=0).max(), 1e-300) ** 2
        tiny = a <= 1e-14 * scale
        if tiny.any():
            first = int(np.flatnonzero(tiny)[0])
            raise ValueError(f"{int(tiny.sum())} degenerate (zero-area) triangles, first is triangle {first}")
        self.V = np.ascontiguousarray(V)
        self.F = np.ascontiguousarray(F)

    # ------------------------------------------------------------------ sizes
    @property
    def n_vertices(self) -> int:
        return len(self.V)

    @property
    def n_faces(self) -> int:
        return len(self.F)

    def __repr__(self):
        return f"Mesh(n_vertices={self.n_vertices}, n_faces={self.n_faces})"

    @cached_property
    def areas(self):
        """(m,) numpy array: rest area A_t of every triangle."""
        return signed_areas(self.V, self.F)

    @cached_property
    def bbox_diagonal(self) -> float:
        """Length of the bounding-box diagonal."""
        return float(np.linalg.norm(np.ptp(self.V, axis=0)))

    # ------------------------------------------------------------- boundary
    def boundary_loops(self):
        """Boundary loops, outer loop first (longest), each a (k,) int array."""
        loops = igl.boundary_loop_all(self.F) if hasattr(igl, "boundary_loop_all") else [igl.boundary_loop(self.F)]
        loops = [np.asarray(loop, dtype=np.int64) for loop in loops]
        return sorted(loops, key=lambda loop: -len(loop))

    # ------------------------------------------------------------ Jacobians
    @cached_property
    def local_gradients(self):
        """(m,3,2) numpy array: ∇φ_i of the three hat functions on every triangle.

        For a piecewise-linear map with vertex positions X, the Jacobian on
        triangle t is ``J_t = X[F[t]].T @ local_gradients[t]`` (2×2).
        """
        P = self.V[self.F]  # (m,3,2)
        E = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=2)  # (m,2,2) columns e1,e2
        Einv = np.linalg.inv(E)  # rows: ∇λ1, ∇λ2
        g12 = Einv  # (m,2,2): row i = grad of barycentric λ_{i+1}
        g0 = -g12.sum(axis=1, keepdims=True)
        return np.ascontiguousarray(np.concatenate([g0, g12], axis=1))

    def jacobians(self, X):
        """Per-triangle Jacobians of the piecewise-linear map X.

        Parameters
        ----------
        X : (n,2) numpy array
            Deformed vertex positions.

        Returns
        -------
        J : (m,2,2) numpy array
            ``J[t, a, b] = ∂X_a/∂x_b`` on triangle t.
        """
        X = np.asarray(X, dtype=float)
        if X.shape != self.V.shape:
            raise ValueError(f"X must have shape {self.V.shape}, got {X.shape}")
        return (self.jacobian_operator @ X.ravel()).reshape(-1, 2, 2)  # sparse: 15x faster than einsum

    @cached_property
    def jacobian_operator(self):
        """Sparse (4m, 2n) operator G with ``G @ X.ravel() == jacobians(X).reshape(-1)``.

        ``X.ravel()`` is row-major (x0, y0, x1, y1, ...); each block of four rows
        is (J00, J01, J10, J11) of one triangle.
        """
        m = self.n_faces
        D = self.local_gradients  # (m,3,2)
        t = np.arange(m)
        rows, cols, vals = [], [], []
        for a in range(2):
            for b in range(2):
                for i in range(3):
                    rows.append(4 * t + 2 * a + b)
                    cols.append(2 * self.F[:, i] + a)
                    vals.append(D[:, i, b])
        G = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(4 * m, 2 * self.n_vertices),
        )
        return G

    def flipped(self, X):
        """(m,) bool array: triangles whose orientation X reverses or collapses (det J ≤ 0)."""
        return signed_areas(X, self.F) <= 0

    # ------------------------------------------------------- FEM matrices
    @cached_property
    def mass_matrix(self):
        """(n,n) scipy sparse: lumped (Voronoi) mass matrix A of the hat functions (libigl)."""
        return igl.massmatrix(self.V, self.F, igl.MASSMATRIX_TYPE_VORONOI).tocsr()

    @cached_property
    def mass_matrix_full(self):
        """(n,n) scipy sparse: consistent (full) FEM mass matrix, A_ii' = ∫ φ_i φ_i' (libigl)."""
        return igl.massmatrix(self.V, self.F, igl.MASSMATRIX_TYPE_FULL).tocsr()

    @cached_property
    def cotmatrix(self):
        """(n,n) scipy sparse: cotangent Laplacian L (negative semi-definite, libigl)."""
        return igl.cotmatrix(self.V, self.F).tocsr()

    # -------------------------------------------------------------- lookup
    @cached_property
    def _kdtree(self):
        return cKDTree(self.V)

    def nearest_vertex(self, points):
        """Nearest mesh vertex of each point.

        Parameters
        ----------
        points : (k,2) numpy array

        Returns
        -------
        idx : (k,) int array
        dist : (k,) numpy array
        """
        points = _check_V(np.atleast_2d(points), "points")
        dist, idx = self._kdtree.query(points)
        return np.asarray(idx, dtype=np.int64), np.asarray(dist)

    def contains(self, points):
        """(k,) bool array: whether each point lies in Ω (inside some triangle)."""
        points = _check_V(np.atleast_2d(points), "points")
        # barycentric test against triangles near the nearest vertex is not exact
        # for concave shapes; use the robust full test with a tolerance.
        P = self.V[self.F]
        out = np.zeros(len(points), dtype=bool)
        for k, p in enumerate(points):
            d0 = P[:, 0] - p
            d1 = P[:, 1] - p
            d2 = P[:, 2] - p
            c0 = d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0]
            c1 = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
            c2 = d2[:, 0] * d0[:, 1] - d2[:, 1] * d0[:, 0]
            eps = -1e-12 * self.bbox_diagonal**2
            out[k] = bool(np.any((c0 >= eps) & (c1 >= eps) & (c2 >= eps)))
        return out

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
    """Write a mesh.

    ``.npz`` is exact. ``.obj``/``.off`` go through libigl with z = 0 and
    17 significant digits, so the round trip is exact for float64 too.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".npz":
        np.savez(path, V=mesh.V, F=mesh.F)
    elif ext in (".obj", ".off"):
        V3 = np.hstack([mesh.V, np.zeros((mesh.n_vertices, 1))])
        igl.write_triangle_mesh(str(path), V3, mesh.F.astype(np.int64), igl.FileEncoding.Ascii)
    else:
        raise ValueError(f"unknown mesh format {ext!r}; use .npz, .obj or .off")


def read_mesh(path):
    """Read a mesh written by :func:`write_mesh` (or any planar OBJ/OFF)."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no such mesh file: {path}")
    ext = path.suffix.lower()
    if ext == ".npz":
        with np.load(path) as d:
            if "V" not in d or "F" not in d:
                raise ValueError(f"{path} holds no mesh (arrays V and F are missing)")
            return Mesh(d["V"], d["F"])
    if ext in (".obj", ".off"):
        V, F = igl.read_triangle_mesh(str(path))
        V = np.asarray(V, dtype=float)
        if V.shape[1] == 3:
            if np.abs(V[:, 2]).max(initial=0) > 0:
                raise ValueError(f"{path} is not planar (z is not 0)")
            V = V[:, :2]
        return Mesh(V, F)
    raise ValueError(f"unknown mesh format {ext!r}; use .npz, .obj or .off")
