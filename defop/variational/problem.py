"""Problem (6) reduced to the free vertices: handles eliminated, targets, E, its gradient and Hessian.

min_X E(X) = Σ_t A_t ψ(J_t(X)) subject to X[handles] = targets, over piecewise-linear maps X (n, d) on a mesh
of elements of d + 1 vertices (triangles in 2D, tetrahedra in 3D): d is read from ``mesh.V``. The handles are
hard constraints, eliminated from the system: only the d·n_free free dofs are unknowns. :class:`ReducedProblem`
holds what depends only on the mesh, the handle set and the energy; :class:`ReducedHessian` the fixed sparsity
pattern of the Hessian Σ_t A_t B_tᵀ H_t B_t and its factorisation (QDLDL: the AMD ordering and the symbolic
analysis are computed once and reused by every ``update``; scipy's SuperLU is the fallback without qdldl). The
factorisation back end is chosen in :mod:`defop.variational.backend`, the arguments are checked in
:mod:`defop.variational.checks`; both modules' public names are importable from here too.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from . import backend as bk
from . import energies as en
from . import work
from .backend import (  # noqa: F401 (public here too)
    BACKENDS,
    FALLBACK_COST,
    HAVE_PARDISO,
    PARDISO_MIN_VERTICES_3D,
    PardisoLDL,
    check_backend,
    choose_backend,
    mkl_error,
    mkl_threads,
    pardiso_solver,
)
from .checks import (  # noqa: F401 (public here too)
    MAX_TARGET_DISTANCE,
    check_handle_span,
    check_handles,
    check_max_iter,
    check_start,
    check_targets,
    check_tol,
    count_flips,
)
from .elements import KERNELS, ElementKernels, check_kernel  # noqa: F401 (KERNELS, check_kernel: public here too)


class ReducedHessian:
    """The Hessian on the free dofs: a fixed sparsity pattern, assembly, an LDLᵀ and its inertia.

    The upper triangle of the free-free block is assembled in CSC order (QDLDL's input), so only its values
    change between iterations; QDLDL computes the AMD ordering and the symbolic analysis once and reuses them
    in every ``update``. Without qdldl, SuperLU (no inertia). The one interface to the factorisation:
    :meth:`solve` and :meth:`inertia`, whatever the back end (:func:`choose_backend`: qdldl, MKL PARDISO
    through :class:`PardisoLDL`, or SuperLU).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        V (n, d), F (m, d + 1).
    free : (n_free·d,) int numpy array
        The free dofs (d·vertex + coordinate), sorted.
    backend : str, optional
        One of :data:`BACKENDS` (default ``DEFOP_BACKEND``, else ``"auto"``).

    Attributes
    ----------
    backend : str
        The factorisation in use: "qdldl", "pardiso" or "splu".
    reuse : bool
        Whether :meth:`solve` with ``reuse`` > 0 (a Newton step) may precondition conjugate gradients with the last
        Newton step's factorisation instead of factorising (:func:`defop.variational.backend.choose_reuse`:
        ``DEFOP_REUSE``, by default from :data:`~defop.variational.backend.REUSE_MIN_UNKNOWNS` unknowns, i.e. off);
        settable.
    """

    def __init__(self, mesh, free, backend=None):
        self.backend = bk.choose_backend(backend, mesh.n_vertices, mesh.V.shape[1])
        # the mesh's pattern over every dof (built once per mesh, Mesh.dof_pairs), restricted to the free dofs: the
        # numbering d·v + c -> rank among the free dofs keeps the order, so its CSC order is the pattern's own
        dofs, pairs, inverse = mesh.dof_pairs
        n_dofs, nf = mesh.V.size, len(free)
        is_free = np.zeros(n_dofs, bool)
        is_free[free] = True
        gmap = np.cumsum(is_free) - 1
        on = is_free[dofs]  # (m, k): local dofs (d+1)·d per element
        self._keep = np.flatnonzero((inverse >= 0) & (on[:, :, None] & on[:, None, :]).ravel())  # free-free, upper
        self.dofs = dofs
        self.nf = nf
        pr, pc = pairs % n_dofs, pairs // n_dofs
        on_free = is_free[pr] & is_free[pc]
        self._inv = (np.cumsum(on_free) - 1)[inverse[self._keep]]
        uniq = gmap[pc[on_free]] * nf + gmap[pr[on_free]]  # column-major = CSC
        self._rows = (uniq % nf).astype(np.int32)
        self._ptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // nf, minlength=nf))]).astype(np.int32)
        #: values in the pattern (the length of every ``data`` array)
        self.nnz = len(uniq)
        #: the slots of the diagonal entries in ``data``
        self.diag = np.searchsorted(uniq, uniq[(uniq % nf) == (uniq // nf)])
        self._K = self._factor = self._slot = None
        #: nonzeros of the factor L (the back end's ordering), known after the first factorisation: what each
        #: factorisation adds to :func:`defop.variational.work.total`
        self.factor_nnz = None
        #: the values of the last factorised matrix (None: none, or it failed)
        self._factored = None
        self.reuse = bk.choose_reuse(nf, self.backend)
        #: whether the kept factorisation is a Newton step's, which a later Newton step may re-use, and whether
        #: CG on it stalled since :meth:`forget`
        self._stale, self._stalled = False, 0
        #: "numba": :meth:`assemble` runs :func:`defop.variational.fused.scatter`; "numpy": the reference
        self.kernel = "numba"

    def __getstate__(self):
        state = {"_K": None, "_factor": None, "_factored": None, "_slot": None, "_stale": False, "_stalled": 0}
        return {**self.__dict__, **state}

    @property
    def slot(self):
        """(m, (d+1)d, (d+1)d) element → CSC slot map of the fused kernels (−1: not kept), built on first use."""
        if self._slot is None:
            from . import fused

            k = self.dofs.shape[1]
            self._slot = fused.slot_map(self._keep, self._inv, len(self.dofs), k)
        return self._slot

    def assemble(self, local, project=True):
        """Values in the pattern from per-element modes W (m, (d+1)d, d²) and A_t·λ (m, d²); ``project`` clamps
        the element eigenvalues at 0 (the PSD projection)."""
        W, lamA = local
        if self.kernel == "numba":
            from . import fused

            data = np.empty(self.nnz)
            fused.scatter(W, lamA, self.slot, bool(project), data)
            return data
        if project:
            lamA = np.maximum(lamA, 0.0)
        K_loc = np.matmul(W * lamA[:, None, :], np.swapaxes(W, 1, 2))  # (m, (d+1)d, (d+1)d)
        return np.bincount(self._inv, weights=K_loc.reshape(-1)[self._keep], minlength=self.nnz)

    def matrix(self, data, rel_shift=0.0):
        """The upper-triangular CSC matrix with these values plus ``rel_shift`` · mean|diag| on the diagonal."""
        if self._K is None:  # the pattern is fixed: build the matrix once, then only overwrite its values
            self._K = sp.csc_matrix((data.copy(), self._rows, self._ptr), shape=(self.nf, self.nf))
        self._K.data[:] = data
        self._K.data[self.diag] += self.shift(data, rel_shift)
        return self._K

    def shift(self, data, rel_shift):
        """The diagonal shift :meth:`matrix` adds: ``rel_shift`` · mean|diag| (at least 1e-300 of mean|diag|)."""
        return rel_shift * max(float(np.mean(np.abs(data[self.diag]))), 1e-300)

    def full(self, data):
        """The symmetric matrix (both triangles), CSC."""
        K = self.matrix(data).copy()
        return (K + sp.triu(K, 1).T).tocsc()

    def solve(self, data, b, rel_shift, reuse=0.0):
        """K⁻¹ b with K = ``matrix(data, rel_shift)``: factorises, unless ``reuse`` (a Newton step's relative
        residual, :func:`defop.variational.backend.forcing`) and :attr:`reuse`.

        Then the last Newton step's factorisation preconditions conjugate gradients
        (:func:`defop.variational.backend.pcg`, to a relative residual of ``reuse``), and K is factorised only
        when they stall. A solve with ``reuse=False`` (the inertia of the verification and the kink's pull) always
        has K's own factorisation, so :meth:`inertia` is K's; call :meth:`forget` where a new solve begins. A K equal
        value for value to the one factorised last is not factorised again: the verification's exact Hessian, at
        the point where the solve's last held Newton system was just factorised, costs one back-substitution."""
        K = self.matrix(data, rel_shift)
        if reuse and self.reuse and self._stale and self._stalled < bk.REUSE_STALLS:
            found = bk.pcg(K, b, self._factor.solve, reuse)
            self._stalled = 0 if found is not None else self._stalled + 1
            if found is not None:
                return found[0]
        x = self.factorise(K, b)  # a K equal to the one factorised last re-uses its factors (:meth:`factorise`)
        self._stale = bool(reuse and self.reuse)
        return x

    def forget(self):
        """No Newton step re-uses the kept factorisation, and a stall is forgotten: a solve's directions depend on
        its own steps only."""
        self._stale, self._stalled = False, 0

    def factorise(self, K, b):
        """Factorise K (upper CSC) with the back end, keeping the factorisation; K⁻¹ b.

        A K equal value for value to the last one factorised (the verification at the point where the held μ = 0
        stage ended on the same matrix) re-uses its factors: the same solution and inertia, bit for bit."""
        if self.backend == "splu":  # pragma: no cover - exercised only without qdldl
            lu = sla.splu((K + sp.triu(K, 1).T).tocsc(), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
            self.factor_nnz = lu.L.nnz + lu.U.nnz
            work.add(self.factor_nnz, K.nnz)
            return lu.solve(b)
        if self._factored is not None and np.array_equal(self._factored, K.data):
            return self._factor.solve(b)
        self._factored = None
        x = self._factorise(K, b)
        self._factored = K.data.copy()
        return x

    def _factorise(self, K, b):
        """:meth:`factorise` without the re-use: the back end's numeric factorisation."""
        if self.backend == "pardiso":
            if self._factor is None:
                self._factor = bk.PardisoLDL(K)
            self._factor.factor(K)
        elif self._factor is None:
            self._factor = bk.qdldl.Solver(K, upper=True)
        else:
            self._factor.update(K, upper=True)
        if self.factor_nnz is None:  # the pattern is fixed: so is the factor's (symbolic) fill
            self.factor_nnz = self._factor.nonzeros() if self.backend == "pardiso" else self._factor.factors()[0].nnz
        work.add(self.factor_nnz, K.nnz)
        return self._factor.solve(b)

    def inertia(self):
        """Negative eigenvalues of the last factorised K (Sylvester: qdldl's negative pivots, PARDISO's
        iparm[22]); None with SuperLU, which gives no inertia."""
        if self._factor is None or self.backend == "splu":
            return None
        if self.backend == "pardiso":
            return self._factor.inertia()
        return int(np.count_nonzero(self._factor.factors()[1] < 0))


class ReducedProblem:
    """Problem (6) on one mesh, one handle set and one energy, reduced to the free vertices.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        V (n, d), F (m, d + 1); d is read from V.
    handles : (h,) int numpy array or (n_vertices,) bool numpy array
        Constrained vertices (moving and fixed handles), in any order (see :func:`check_handles`).
        Targets are always given in this order. A vertex listed twice must get the same target each time.
    energy : str
        One of :data:`defop.variational.energies.ENERGIES`.
    backend : str, optional
        The factorisation, one of :data:`BACKENDS` (default ``DEFOP_BACKEND``, else ``"auto"``); every back end
        gives the same minima (tests/test_backend.py), so it is not a setting of the solutions.
    kernel : str, optional
        The element kernels, one of :data:`KERNELS` (default ``DEFOP_KERNEL``, else ``"numba"``); both give the same
        values to round-off (tests/test_fused_kernel.py). Settable later as the ``kernel`` attribute.

    Attributes
    ----------
    handles : (u,) int numpy array
        The unique handle vertices, sorted. ``handles_given`` keeps the order of the constructor.
    free_vertices : (n_free,) int numpy array
    free : (n_free·d,) int numpy array
        The free dofs d·v + c, the unknowns.
    hessian : ReducedHessian
    """

    def __init__(self, mesh, handles, energy="sarap", backend=None, kernel=None):
        self.mesh = mesh
        self.energy = en.check_energy(energy)
        self.barrier = en.is_barrier(energy)
        self.handles_given = check_handles(mesh, handles)
        #: unique sorted handle vertices; ``targets_given[k]`` belongs to ``handles[_slot[k]]``
        self.handles, self._slot = np.unique(self.handles_given, return_inverse=True)
        n, d = mesh.V.shape
        if len(self.handles) == n:
            raise ValueError(f"every one of the {n} vertices is a handle: there is nothing to solve for")
        is_handle = np.zeros(n, bool)
        is_handle[self.handles] = True
        self.free_vertices = np.flatnonzero(~is_handle)
        self.free = (d * self.free_vertices[:, None] + np.arange(d)).ravel()
        self.hessian = ReducedHessian(mesh, self.free, backend)
        self.elements = ElementKernels(mesh, self.energy, self.hessian, kernel)
        self._biharmonic = None
        #: nonzeros of the bi-Laplacian's LU factors (the rest pose's start), 0 until it is built
        self.biharmonic_nnz = 0
        #: energies below this (1e-12 · area) count as zero in relative tests (ARAP and S-ARAP vanish at rest)
        self._energy_floor = 1e-12 * float(mesh.areas.sum())

    def __getstate__(self):
        return {**self.__dict__, "_biharmonic": None}

    @property
    def dim(self) -> int:
        """d: 2 for triangles, 3 for tetrahedra (:attr:`defop.geometry.mesh.Mesh.dim`)."""
        return self.mesh.dim

    @property
    def kernel(self) -> str:
        """The element kernels in use, "numba" or "numpy" (:data:`KERNELS`); setting it switches the assembly too."""
        return self.elements.kernel

    @kernel.setter
    def kernel(self, kernel):
        self.elements.kernel = kernel

    def scale(self, E):
        """E as the scale of relative tests: at least 1e-12 · area (ARAP and S-ARAP vanish at rest)."""
        return max(E, self._energy_floor)

    def targets_of(self, targets):
        """Validate targets given in the constructor's handle order; return them per unique handle.

        Parameters
        ----------
        targets : (h, d) array-like
            One row per entry of the ``handles`` given to the constructor.

        Returns
        -------
        T : (u, d) numpy array
            ``T[j]`` is the target of vertex ``self.handles[j]``.
        """
        Tg = check_targets(targets, self.handles_given, self.mesh)
        T = np.empty((len(self.handles), self.dim))
        T[self._slot] = Tg
        bad = np.flatnonzero(np.abs(Tg - T[self._slot]).max(axis=1) > 1e-12 * self.mesh.bbox_diagonal)
        if len(bad):
            k = int(bad[0])
            v = int(self.handles_given[k])
            raise ValueError(
                f"vertex {v} is given two different targets: {T[self._slot[k]].tolist()} and {Tg[k].tolist()}"
            )
        return T

    # ------------------------------------------------------------------ energy pieces (:class:`ElementKernels`)
    def jacobians(self, X):
        """(m, d, d) Jacobians of the map X (n, d), from the mesh's sparse operator."""
        return self.elements.jacobians(X)

    def energy_of(self, X, mu=0.0):
        """E(X) (+inf for a flipped element under a barrier energy); ``mu`` smooths S-ARAP's kink."""
        return self.energies(X, mu)[0] if mu else self.energies(X, 0.0)[1]

    def energies(self, X, mu):
        """(E_μ(X), E(X)): :meth:`ElementKernels.energies`."""
        return self.elements.energies(X, mu)

    def grad_hess(self, X, mu=0.0, project=True, kink=0.0):
        """E, ∇E (d·n,), the Hessian values in the fixed CSC pattern and ``local``: :meth:`ElementKernels.grad_hess`."""
        return self.elements.grad_hess(X, mu, project, kink)

    def newton_direction(self, g_free, data, rel_shift=1e-10, reuse=0.0):
        """−K⁻¹ g on the free dofs. A tiny relative diagonal shift keeps the projected (PSD) Hessian definite;
        the exact Hessian may be indefinite: the caller checks that the direction descends. ``reuse`` > 0: a Newton
        step, which may re-use an earlier step's factorisation to this relative residual
        (:meth:`ReducedHessian.solve`)."""
        return -self.hessian.solve(data, g_free, rel_shift, reuse)

    def full(self, p):
        """(n, d) field from free-dof values ``p`` (zero at the handles)."""
        P = np.zeros(self.dim * self.mesh.n_vertices)
        P[self.free] = p
        return P.reshape(-1, self.dim)

    # ------------------------------------------------------------------ starts
    def extend(self, displacement):
        """Biharmonic extension (n, d) of the unique handles' displacements (u, d): :func:`biharmonic_extension`.

        A zero displacement (a start whose handles sit on their targets, such as a prolongated coarse minimum) extends
        to zero without a solve: the same sums as the solve's ±0 (x + (−0) = x), one bi-Laplacian back-substitution
        (22 ms at 30k vertices) saved per such start."""
        displacement = np.asarray(displacement, float)
        if displacement.shape == (len(self.handles), self.mesh.dim) and not np.any(displacement):
            return np.zeros(self.mesh.V.shape)
        if self._biharmonic is None:
            self._biharmonic = biharmonic_factors(self.mesh, self.free_vertices, self.handles)
            self.biharmonic_nnz = self._biharmonic[0].L.nnz + self._biharmonic[0].U.nnz
        return biharmonic_extension(self._biharmonic, self.mesh, self.free_vertices, self.handles, displacement)

    def check_start(self, X0):
        """A copy of the start X0 (n, d), or of the rest pose when None: :func:`check_start`."""
        return check_start(self.mesh, X0, self.energy)


def biharmonic_factors(mesh, free_vertices, handles):
    """The factorised bi-Laplacian L M⁻¹ L on the free vertices and its handle columns (:func:`biharmonic_extension`).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    free_vertices, handles : int numpy arrays
        A partition of the vertices.

    Returns
    -------
    factors : (scipy SuperLU of the free block, (n_free, u) sparse matrix)
    """
    Q = mesh.bilaplacian
    return sla.splu(Q[free_vertices][:, free_vertices].tocsc()), Q[free_vertices][:, handles].tocsc()


def biharmonic_extension(factors, mesh, free_vertices, handles, displacement):
    """Biharmonic extension of handle displacements to the whole mesh.

    Parameters
    ----------
    factors : tuple
        :func:`biharmonic_factors` of the same partition.
    mesh : defop.geometry.mesh.Mesh
    free_vertices, handles : int numpy arrays
    displacement : (u, d) numpy array
        Displacement of each handle vertex, in the order of ``handles``.

    Returns
    -------
    D : (n, d) numpy array
        Zero-Laplacian-squared displacement field equal to ``displacement`` at the handles.
    """
    lu, Qfh = factors
    D = np.zeros(mesh.V.shape)
    D[handles] = displacement
    D[free_vertices] = -lu.solve(np.asarray(Qfh @ displacement))
    return D
