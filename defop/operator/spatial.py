"""Spatial bases Φ (§3.1): hat functions, or a reduced, linearly precise eigenbasis.

A spatial basis is stored by its values at the vertices, ``U (n_vertices, |Φ|)``: column i is φ_i.
The operator's spatial part is then D(·, Q) = U C Ψ(Q) (Eq. 3).

* **Hat functions** (FEM): Φ is the identity over the vertices, |Φ| = n_vertices.
* **Reduced basis**: the k lowest eigenfunctions (default k = 100) of a *linearly precise* smoothness
  energy, ordered by eigenvalue and orthonormal in the mass matrix M. Wang, Jacobson, Barbič & Kavan
  (2015) ask for a squared-Laplacian energy whose null space is exactly the affine functions; their
  boundary correction has a published erratum, and a squared Laplacian with any boundary flux
  correction still (nearly) annihilates every harmonic function, an infinite-dimensional space (we
  measured a 4th singular value of 3e-10 on the aleph). We use instead the Hessian energy
  ∫_Ω ‖Hess u‖²_F of Stein, Grinspun, Wardetzky & Jacobson (2018, "Natural boundary conditions for
  smoothing in geometry processing"), discretised by mixed FEM in libigl (``igl.hessian_energy``): its
  null space on a flat domain is exactly {1, x, y}. This is tested, and the three affine functions are
  put first, exactly, so the span reproduces x and y to round-off. libigl's ``biharmonic_coordinates``
  would use a Crouzeix–Raviart construction instead.

Dimension: d is read from the mesh (``V.shape[1]``). Hat functions and the mass matrix (lumped areas, or
volumes on tetrahedra) work for d = 2 and 3. The reduced basis' energy is libigl's mixed-FEM Hessian energy on
triangles; on tetrahedra libigl has no Hessian energy, so it is the affine-residual energy uᵀRᵀRu alone
(:func:`affine_residual_operator`), which is linearly precise too: its null space is exactly {1, x, y, z}.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

KINDS = ("hat", "reduced")


@dataclasses.dataclass(eq=False)
class SpatialBasis:
    """Φ as values at the vertices.

    Attributes
    ----------
    kind : str
        ``"hat"`` or ``"reduced"``.
    U : (n_vertices, |Φ|) scipy sparse identity or numpy array
        Column i holds φ_i at the vertices.
    mass : (n_vertices, n_vertices) scipy sparse matrix
        The lumped mass matrix M (the L² inner product of Appendix A).
    eigenvalues : (|Φ|,) numpy array or None
        For the reduced basis: the eigenvalues of Q (the first three are 0).
    """

    kind: str
    U: object
    mass: object
    eigenvalues: np.ndarray | None = None

    @property
    def size(self) -> int:
        """|Φ|."""
        return self.U.shape[1]

    @property
    def n_vertices(self) -> int:
        return self.U.shape[0]

    def coefficients(self, X):
        """L²(M)-projection of vertex data onto span Φ.

        Parameters
        ----------
        X : (n_vertices, d) or (..., n_vertices, d) numpy array

        Returns
        -------
        A : (|Φ|, d) or (..., |Φ|, d) numpy array
            ``X ≈ U @ A``; exact for hat functions, and for x, y and constants with the reduced basis.
        """
        X = np.asarray(X, float)
        if self.kind == "hat":
            return X.copy()
        MX = self.mass.diagonal()[:, None] * X  # the lumped (diagonal) mass matrix
        if MX.ndim == 2:
            return self.U.T @ MX
        # one matrix product over every configuration (BLAS), not k products of width d; any leading dimensions
        lead, (n, d) = MX.shape[:-2], MX.shape[-2:]
        flat = MX.reshape(-1, n, d)
        A = self.U.T @ flat.transpose(1, 0, 2).reshape(n, -1)  # (p, k d)
        A = A.reshape(self.size, len(flat), d).transpose(1, 0, 2)
        return np.ascontiguousarray(A).reshape(*lead, self.size, d)

    def evaluate(self, A):
        """Vertex values of Σ_i A_i φ_i.

        Parameters
        ----------
        A : (|Φ|, d) numpy array

        Returns
        -------
        X : (n_vertices, d) numpy array
        """
        return np.asarray(self.U @ A)


def hat_basis(mesh):
    """The :class:`SpatialBasis` of hat functions over ``mesh``: Φ is the identity over the vertices."""
    return SpatialBasis("hat", sp.identity(mesh.n_vertices, format="csr"), mesh.mass_matrix)


def hessian_energy(mesh):
    """The Hessian energy matrix Q: uᵀQu ≈ ∫_Ω ‖Hess u‖²_F (libigl, mixed FEM; Stein et al. 2018).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh

    Returns
    -------
    Q : (n,n) scipy.sparse.csc_matrix
        Symmetric positive semi-definite; Q @ [1, x, y] = 0 (Q @ [1, x, y, z] = 0 on tetrahedra, where Q is RᵀR).
    """
    import igl

    if mesh.V.shape[1] != 2:  # libigl's Hessian energy is for triangle meshes
        R = affine_residual_operator(mesh)
        return (R.T @ R).tocsc()
    Q = igl.hessian_energy(np.ascontiguousarray(mesh.V), np.ascontiguousarray(mesh.F, dtype=np.int64))
    Q = ((Q + Q.T) / 2).tocsr()
    R = affine_residual_operator(mesh)
    RtR = (R.T @ R).tocsr()
    w = 1e-2 * np.mean(np.abs(Q.diagonal())) / np.mean(RtR.diagonal())
    return (Q + w * RtR).tocsc()


def affine_residual_operator(mesh):
    """R, an (n,n) scipy.sparse.csr_matrix on ``mesh``'s vertices: (R u)_i = u_i − (the minimum-norm affine
    extrapolation of u from the 1-ring of i).

    R annihilates exactly the affine functions (on a connected mesh), so Σ_i (R u)_i² is a linearly
    precise smoothness energy. The mixed-FEM Hessian energy measures second derivatives on interior edges
    only, so a vertex at a sharp boundary corner gets almost no stiffness and adds a spurious null vector
    (measured: 2 extra on the aleph's acute corners). Adding 1% of RᵀR (scaled to Q's diagonal) removes
    them and keeps the null space exactly {1, x, y}.
    """
    n = mesh.n_vertices
    k = mesh.F.shape[1]  # vertices per element: 3 (triangles) or 4 (tetrahedra)
    pairs = [(i, (i + 1) % k) for i in range(k)] + [(i, i + 2) for i in range(k - 2) if k > 3]  # every edge
    E = np.concatenate([mesh.F[:, list(p)] for p in pairs])
    A = sp.csr_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    A = ((A + A.T) > 0).tocsr()
    rows, cols, vals = [], [], []
    for i in range(n):
        nb = A.indices[A.indptr[i] : A.indptr[i + 1]]
        B = np.vstack([np.ones(len(nb)), mesh.V[nb].T])  # (1 + d, k)
        if np.linalg.cond(B @ B.T) > 1e10:  # collinear 1-ring (a corner): use the 2-ring
            nb = np.setdiff1d(np.unique(np.concatenate([A.indices[A.indptr[j] : A.indptr[j + 1]] for j in nb])), [i])
            B = np.vstack([np.ones(len(nb)), mesh.V[nb].T])
        beta = B.T @ np.linalg.solve(B @ B.T, np.array([1.0, *mesh.V[i]]))
        rows += [i] * (len(nb) + 1)
        cols += [i, *nb]
        vals += [1.0, *(-beta)]
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def reduced_basis(mesh, k=100):
    """The k lowest eigenfunctions of the Hessian energy (generalised by M), M-orthonormal.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    k : int
        |Φ| (at least 3, fewer than the number of vertices).

    Returns
    -------
    basis : SpatialBasis
        ``U[:, :d+1]`` spans {1, x, y} ({1, x, y, z} in 3D) exactly.

    Raises
    ------
    ValueError
        A bad k, or a mesh whose energy has a null space other than {1, x, y} (e.g. a vertex that
        belongs to a single triangle, which the Hessian energy does not constrain).
    """
    n = mesh.n_vertices
    a = mesh.V.shape[1] + 1  # the affine functions: 3 in 2D, 4 in 3D
    if int(k) != k or k < a or k > n - a - 1:  # ARPACK finds at most n - 1 eigenpairs, and k + a are needed
        raise ValueError(f"k must be an integer with {a} <= k <= n_vertices - {a + 1} = {n - a - 1}, got {k!r}")
    k = int(k)
    M = mesh.mass_matrix.tocsc()
    m = M.diagonal()
    Q = hessian_energy(mesh)
    # affine functions first, M-orthonormal
    A = np.column_stack([np.ones(n), mesh.V])
    A = _m_orthonormalize(A, m)
    # a seeded start vector: ARPACK's default is random, which made the basis differ run to run
    v0 = np.random.default_rng(0).standard_normal(n)
    lam, vecs = sla.eigsh(Q, k=k + a, M=M, sigma=-1e-2, which="LM", v0=v0)
    order = np.argsort(lam)
    lam, vecs = lam[order], vecs[:, order]
    if lam[a] < 1e4 * np.abs(lam[:a]).max():
        lone = np.flatnonzero(np.bincount(mesh.F.ravel(), minlength=n) == 1)
        raise ValueError(
            f"the Hessian energy's null space is larger than {{1, x, y}} on this mesh (lowest eigenvalues "
            f"{np.array2string(lam[:5], precision=2)}); {len(lone)} vertices belong to a single triangle"
            + (f" (first: vertex {lone[0]})" if len(lone) else "; is the mesh connected?")
        )
    # remove the affine span from the other eigenvectors (M-orthogonally), keep k - a of them
    rest = vecs[:, a:]
    rest = rest - A @ (A.T @ (m[:, None] * rest))
    rest = _m_orthonormalize(rest, m)
    U = np.column_stack([A, rest[:, : k - a]])
    return SpatialBasis("reduced", U, mesh.mass_matrix, np.concatenate([np.zeros(a), lam[a:k]]))


def _m_orthonormalize(A, m):
    """Columns of A made orthonormal in the inner product diag(m) (two passes of Gram–Schmidt by QR)."""
    s = np.sqrt(m)[:, None]
    for _ in range(2):
        q, _r = np.linalg.qr(s * A)
        A = q / s
    return A


#: the last few reduced bases built in this process, by the mesh's bytes and k (a fit, a refit and Table 1's timings
#: of one model build the same Φ; an eigensolve each is seconds on the octopus)
_REDUCED = {}
_REDUCED_KEPT = 4


def _remembered_reduced(mesh, k):
    """:func:`reduced_basis`, built once per mesh (its V and F bytes) and k among the last :data:`_REDUCED_KEPT`."""
    import hashlib

    V, F = np.ascontiguousarray(mesh.V), np.ascontiguousarray(mesh.F)
    key = (hashlib.blake2b(V.tobytes() + F.tobytes() + str((V.shape, F.shape, k)).encode()).hexdigest(), k)
    if key not in _REDUCED:
        while len(_REDUCED) >= _REDUCED_KEPT:
            _REDUCED.pop(next(iter(_REDUCED)))
        basis = reduced_basis(mesh, k)
        basis.U.setflags(write=False)  # shared by every caller: nobody writes it
        _REDUCED[key] = basis
    return _REDUCED[key]


def make_spatial(mesh, kind="hat", k=100):
    """Build Φ by name.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    kind : str
        ``"hat"`` or ``"reduced"``.
    k : int
        Size of the reduced basis.

    Returns
    -------
    basis : SpatialBasis
    """
    if kind == "hat":
        return hat_basis(mesh)
    if kind == "reduced":
        return _remembered_reduced(mesh, k)
    raise ValueError(f"unknown spatial basis {kind!r}; known: {', '.join(KINDS)}")
