"""Triangle meshes of a planar domain Ω and the operators the paper builds on them.

A :class:`Mesh` holds ``V (n,2)`` and ``F (m,3)`` with counter-clockwise triangles.
It supplies what problem (6) and problem (8) need: triangle areas, the per-triangle
Jacobian J of a piecewise-linear map ``X (n,2)`` (the deformation gradient of
f_Φ, Eq. 1), the mass matrix A (Appendix A) and the cotangent Laplacian.
"""

from __future__ import annotations

import io
import os
import tokenize
import zlib
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


def _check_F(F, n):
    """F as an (m,3) int64 array of indices into n vertices; ValueError naming the bad entry."""
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"F must have shape (m,3), got {F.shape}")
    if len(F) == 0:
        raise ValueError("F has no triangles")
    if F.dtype == bool or not (np.issubdtype(F.dtype, np.integer) or np.issubdtype(F.dtype, np.floating)):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    if not np.issubdtype(F.dtype, np.integer):
        bad = ~np.isfinite(F) | (F != np.round(F))
        if bad.any():
            t, j = (int(x) for x in np.argwhere(bad)[0])
            raise ValueError(f"F must hold integer vertex indices: triangle {t} has {F[t, j].item()!r}")
    bad = (F < 0) | (F >= n)
    if bad.any():
        t, j = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(
            f"triangle {t} indexes vertex {F[t, j].item()!r}, but V has {n} vertices (valid indices 0 to {n - 1})"
        )
    return F.astype(np.int64)


def _orient(F, a):
    """F counter-clockwise: all-clockwise input is flipped; a mix means inverted triangles."""
    cw = a < 0
    if cw.all():
        return np.ascontiguousarray(F[:, [0, 2, 1]])
    if cw.any():
        t = int(np.flatnonzero(cw)[0])
        raise ValueError(
            f"triangle {t} is inverted (clockwise, signed area {a[t]:.3g}) while {int((~cw).sum())} triangles are "
            f"counter-clockwise ({int(cw.sum())} inverted in all): the mesh folds over itself"
        )
    return F


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


class Mesh:
    """A triangulated planar domain Ω.

    Parameters
    ----------
    V : (n,2) numpy array
        Vertex positions (float64).
    F : (m,3) numpy int array
        Triangles, all counter-clockwise or all clockwise (then re-oriented).

    Raises
    ------
    ValueError
        For wrong shapes, non-finite coordinates, out-of-range indices,
        degenerate (zero-area) triangles, inverted triangles (a mesh that folds
        over itself), edges shared by more than two triangles, vertices where
        separate fans meet, or vertices no
        triangle uses; the message names the triangle, edge or vertex.
    """

    def __init__(self, V, F):
        V = _check_V(V)
        F = _check_F(F, len(V))
        a = signed_areas(V, F)
        scale = max(np.ptp(V, axis=0).max(), 1e-300) ** 2
        tiny = np.abs(a) <= 1e-14 * scale
        if tiny.any():
            first = int(np.flatnonzero(tiny)[0])
            raise ValueError(f"{int(tiny.sum())} degenerate (zero-area) triangles, first is triangle {first}")
        F = _orient(F, a)
        _check_manifold(F)
        unused = np.flatnonzero(np.bincount(F.ravel(), minlength=len(V)) == 0)
        if len(unused):
            raise ValueError(
                f"{len(unused)} vertices are not used by any triangle, first is vertex {int(unused[0])}; "
                "remove them (handle indices refer to rows of V)"
            )
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
        ext = np.ptp(self.V, axis=0)
        return float(np.sqrt(ext[0] * ext[0] + ext[1] * ext[1]))  # element-wise: the same on every BLAS

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
    elif ext in (".obj", ".off"):
        V3 = np.hstack([mesh.V, np.zeros((mesh.n_vertices, 1))])
        F = mesh.F.astype(np.int64)
        opt.write_atomic(path, lambda tmp: _igl_write(tmp, V3, F))
    else:
        raise ValueError(f"unknown mesh format {ext!r}; use .npz, .obj or .off")


#: the most vertices or triangles a mesh file may declare (checked before anything is allocated)
MAX_FILE_ELEMENTS = 10_000_000


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
    if not path.is_file():
        raise ValueError(f"no such mesh file: {path}" if not path.exists() else f"mesh file {path} is not a file")
    V, F = _read_npz(path) if ext == ".npz" else _read_igl(path, ext)
    try:
        return Mesh(V, F)
    except ValueError as exc:
        raise ValueError(f"mesh file {path} holds an invalid mesh: {exc}") from None


def _read_npz(path):
    """V and F of an .npz, each member's header checked before its data is inflated (reads stop at its size)."""
    import zipfile

    if not zipfile.is_zipfile(path):
        raise ValueError(f"mesh file {path} is not an .npz archive (not a zip file: truncated, or another format)")
    arrays = {}
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            if not {"V.npy", "F.npy"} <= names:
                raise ValueError(f"mesh file {path} holds no mesh (arrays V and F are missing)")
            for key in ("V", "F"):
                with zf.open(f"{key}.npy") as fh:
                    arrays[key] = _read_member(fh, path, key)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, zlib.error, NotImplementedError) as exc:
        raise ValueError(f"mesh file {path} is truncated or corrupt ({exc})") from None
    return arrays["V"], arrays["F"]


def _read_member(fh, path, key):
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fh)
        read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, fortran, dtype = read_header(fh, max_header_size=10_000)  # a huge or nested header is refused
    except (ValueError, SyntaxError, TypeError, tokenize.TokenError, RecursionError, MemoryError) as exc:
        # numpy tokenizes the header: "((((" raised tokenize's TokenError, deep nesting a RecursionError
        raise ValueError(f"mesh file {path}: member {key} is not a numpy array ({exc})") from None
    if dtype.hasobject or dtype.kind not in "iuf":
        raise ValueError(f"mesh file {path}: {key} must hold numbers, got dtype {dtype}")
    cols = (2, 3) if key == "V" else (3, 4)  # Mesh itself checks that they fit together
    if len(shape) != 2 or shape[1] not in cols:
        raise ValueError(f"mesh file {path}: {key} must be an (n, {' or '.join(map(str, cols))}) array, "
                         f"got shape {shape}")
    if shape[0] > MAX_FILE_ELEMENTS:
        raise ValueError(f"mesh file {path} declares {shape[0]:,} rows of {key}, limit {MAX_FILE_ELEMENTS:,} "
                         f"(defop.geometry.mesh.MAX_FILE_ELEMENTS)")
    count = int(np.prod(shape))
    data = fh.read(count * dtype.itemsize)  # stops at the declared size: a bomb cannot inflate further
    if len(data) != count * dtype.itemsize:
        raise ValueError(f"mesh file {path}: {key} is truncated ({len(data)} of {count * dtype.itemsize} bytes)")
    arr = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
    return np.array(arr)


def _read_igl(path, ext):
    """V and F of an OBJ/OFF by libigl, after the OFF header's counts are checked against the file's size."""
    size = path.stat().st_size
    if ext == ".off":
        _check_off_header(path, size)
    try:
        V, F = igl.read_triangle_mesh(str(path))
    except (RuntimeError, ValueError, TypeError, MemoryError) as exc:
        raise ValueError(f"mesh file {path} could not be read as {ext} ({type(exc).__name__}: {exc})") from None
    V, F = np.asarray(V, dtype=float), np.asarray(F)
    if V.ndim != 2 or F.ndim != 2 or len(V) == 0 or len(F) == 0:
        raise ValueError(f"mesh file {path} holds no triangle mesh ({ext} read as {V.shape} vertices, "
                         f"{F.shape} faces)")
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
        raise ValueError(f"mesh file {path} declares {n_v:,} vertices and {n_f:,} faces in {size:,} bytes "
                         f"(limit {MAX_FILE_ELEMENTS:,} each, and at least 2 bytes per entry)")


def _igl_write(path, V3, F):
    igl.write_triangle_mesh(str(path), V3, F, igl.FileEncoding.Ascii)
