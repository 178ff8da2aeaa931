"""Problem (6) reduced to the free vertices: handles eliminated, targets, E, its gradient and Hessian.

min_X E(X) = Σ_t A_t ψ(J_t(X)) subject to X[handles] = targets, over piecewise-linear maps X (n, d) on a mesh
of elements of d + 1 vertices (triangles in 2D, tetrahedra in 3D): d is read from ``mesh.V``. The handles are
hard constraints, eliminated from the system: only the d·n_free free dofs are unknowns. :class:`ReducedProblem`
holds what depends only on the mesh, the handle set and the energy; :class:`ReducedHessian` the fixed sparsity
pattern of the Hessian Σ_t A_t B_tᵀ H_t B_t and its factorisation (QDLDL: the AMD ordering and the symbolic
analysis are computed once and reused by every ``update``; scipy's SuperLU is the fallback without qdldl).

The factorisation back end is chosen at run time (:func:`choose_backend`): ``DEFOP_BACKEND=auto|qdldl|pardiso``
or the solver's ``backend`` keyword. ``pardiso`` is MKL PARDISO through the optional ``pypardiso`` (the ``mkl``
extra, x86-64 only; pypardiso is BSD-3, MKL comes under Intel's Simplified Software Licence), a supernodal
symmetric-indefinite LDLᵀ whose inertia (iparm[22]) feeds the saddle verification like qdldl's negative pivots.
``auto`` takes PARDISO for tetrahedral meshes of at least :data:`PARDISO_MIN_VERTICES_3D` vertices, where it wins
(``benchmarks/bench_factor.py --real``), and qdldl everywhere else (2D stays bit-for-bit). Where pypardiso is
installed but MKL's library cannot load, ``auto`` falls back to qdldl with one warning per process
(:func:`choose_backend`), and an explicit ``pardiso`` is a ValueError naming ``DEFOP_BACKEND`` or ``backend``.
"""

from __future__ import annotations

import copy
import ctypes
import importlib.util
import os
import warnings
import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .. import config
from .. import options as opt
from . import energies as en
from .elements import KERNELS, ElementKernels, check_kernel  # noqa: F401 (KERNELS, check_kernel: public here too)

try:  # QDLDL reuses the symbolic factorisation (AMD ordering, elimination tree) across updates
    import qdldl
except ImportError:  # pragma: no cover - exercised only without the dependency
    qdldl = None

#: MKL PARDISO, the optional ``mkl`` extra (x86-64): imported on first use (importing it loads MKL)
HAVE_PARDISO = importlib.util.find_spec("pypardiso") is not None

#: the factorisation back ends a solver can be asked for (``DEFOP_BACKEND`` or ``backend=``)
BACKENDS = ("auto", "qdldl", "pardiso")
#: ``auto`` takes PARDISO on tet meshes from this many vertices. Measured on the real S-ARAP Hessians
#: (``benchmarks/bench_factor.py --real``, one MKL thread), per factorisation it wins in 3D from about 200 vertices
#: (4x qdldl at 512 and 1,000 vertices, 11x on the nut's 3.2k, 26x on the octopus's 10k); loading MKL costs about
#: 1.5 s once per process, which a training on 1k vertices repays within a few samples. In 2D it loses below 10k
#: vertices and wins 1.7x at 30k: 2D keeps qdldl (bit for bit)
PARDISO_MIN_VERTICES_3D = 1000

#: targets farther than this many bounding-box diagonals from the mesh are rejected (the energy overflows)
MAX_TARGET_DISTANCE = 1e6


def count_flips(mesh, X):
    """Number of elements with det J ≤ 0 (flipped or collapsed).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n, d) numpy array

    Returns
    -------
    n : int
    """
    return int(np.count_nonzero(mesh.flipped(X)))


def check_tol(tol, name="tol"):
    """A tolerance: a finite float ≥ 0, else ValueError."""
    try:
        t = float(tol)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number >= 0, got {tol!r}") from None
    if not (np.isfinite(t) and t >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {tol!r}")
    return t


def check_max_iter(max_iter):
    """An iteration limit: an integer ≥ 1 (an integer-valued float is accepted), else ValueError."""
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer, float, np.floating)):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    if not (np.isfinite(max_iter) and max_iter >= 1 and float(max_iter) == int(max_iter)):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    return int(max_iter)


def check_handles(mesh, handles):
    """Validate point handles: vertex indices, or a boolean mask with one entry per vertex.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int array-like or (n_vertices,) bool array-like
        Integer-valued floats (``[3.0, 7.0]``) are accepted as indices; other floats are rejected.
        Order is kept; duplicates are allowed (:meth:`ReducedProblem.targets_of` checks their targets agree).

    Returns
    -------
    handles : (h,) int64 numpy array

    Raises
    ------
    ValueError
        Empty, not 1-d, non-integer, out of range, or a mask of the wrong length.
    """
    h = np.asarray(handles)
    n = mesh.n_vertices
    if h.dtype == bool:
        if h.shape != (n,):
            raise ValueError(f"a boolean handle mask needs one entry per vertex ({n}), got shape {h.shape}")
        h = np.flatnonzero(h)
    if h.ndim != 1 or len(h) == 0:
        raise ValueError(f"handles must be a non-empty 1-d array of vertex indices, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.integer):
        if not np.issubdtype(h.dtype, np.floating):
            raise ValueError(f"handles must be integer vertex indices, got dtype {h.dtype}")
        bad = np.flatnonzero(~np.isfinite(h) | (np.mod(h, 1) != 0))
        if len(bad):
            k = int(bad[0])
            raise ValueError(f"handles must be integer vertex indices; handle {k} is {float(h[k])!r}")
    h = h.astype(np.int64)
    bad = np.flatnonzero((h < 0) | (h >= n))
    if len(bad):
        raise ValueError(
            f"handle {int(bad[0])} is vertex index {int(h[bad[0]])}, out of range for a mesh of {n} vertices"
        )
    return h


def check_handle_span(mesh, handles):
    """In 3D, refuse handles that all lie on one line: a rotation about it costs nothing (singular Hessian).

    The rotations of R^d that fix every handle form a group of dimension (d − k)(d − k − 1)/2, with k the dimension
    of the handles' affine hull (at rest). In 3D that is 1 for handles on one line (two handles, say) and 3 for one
    point: problem (6) then has a circle (or sphere) of minima and its reduced Hessian a null space. In 2D the
    group is the rotations about a single handle, whose problem keeps its old treatment: its minimum is the rest
    pose moved rigidly (E = 0), which the solver starts from.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Valid vertex indices (fixed and moving handles together).

    Raises
    ------
    ValueError
        d ≥ 3 and the handles' rest positions span less than a plane (to 1e-9 of the bounding-box diagonal).
    """
    d = mesh.V.shape[1]
    if d < 3:
        return
    P = mesh.V[np.unique(handles)]
    sv = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    k = int(np.count_nonzero(sv > 1e-9 * mesh.bbox_diagonal))
    if k < d - 1:
        where = "one point" if k == 0 else "one line"
        raise ValueError(
            f"handles must not all lie on one line in {d}D (a rotation about it is free and the Hessian singular): "
            f"the {len(P)} distinct handle vertices lie on {where}; add a handle off it (at least three "
            "non-collinear handles, or a small handle patch)"
        )


def check_targets(targets, handles, mesh=None, dim=2):
    """Validate targets: one finite row per handle, not absurdly far from the mesh.

    Parameters
    ----------
    targets : (h, d) array-like
    handles : (h,) int numpy array
    mesh : defop.geometry.mesh.Mesh, optional
        When given, d is ``mesh.V.shape[1]`` and targets farther than ``MAX_TARGET_DISTANCE`` bounding-box
        diagonals from the mesh's centre are rejected (the energy would overflow to inf: e.g. a target at 1e300).
    dim : int
        d when no mesh is given.

    Returns
    -------
    T : (h, d) float numpy array
    """
    d = dim if mesh is None else mesh.V.shape[1]
    T = opt.real_array("targets", targets)
    if T.shape != (len(handles), d):
        raise ValueError(f"targets must have shape ({len(handles)}, {d}), one row per handle, got {T.shape}")
    if not np.isfinite(T).all():
        k = int(np.argwhere(~np.isfinite(T))[0, 0])
        raise ValueError(f"target {k} of handle vertex {int(handles[k])} is not finite: {T[k]}")
    if mesh is not None:
        diag = mesh.bbox_diagonal
        far = np.abs(T - mesh.V.mean(axis=0)).max(axis=1) / diag  # max-norm: no overflow at 1e300
        if far.max() > MAX_TARGET_DISTANCE:
            k = int(np.argmax(far))
            raise ValueError(
                f"target {k} of handle vertex {int(handles[k])} is {far[k]:.3g} bounding-box diagonals from the "
                f"mesh (more than {MAX_TARGET_DISTANCE:g}): the energy would overflow"
            )
    return T


#: MKL loaded once per process: "solver", the PyPardisoSolver every PardisoLDL copies, or "error", why it cannot load
_MKL: dict = {}
#: the slowdown ``auto`` costs where MKL cannot load (benchmarks/README.md, the 10k-vertex octopus_3d, one thread)
FALLBACK_COST = "20x slower per factorisation and 7.7x per verified solve on the 10k-vertex octopus_3d"


def _source(backend):
    """Where the back-end name came from, for messages: the argument or the environment variable."""
    return "DEFOP_BACKEND" if backend is None else "backend"


def check_backend(backend=None):
    """The back-end name asked for: ``backend``, else ``DEFOP_BACKEND``, else ``"auto"``.

    Raises
    ------
    ValueError
        Not one of :data:`BACKENDS`; ``"pardiso"`` without pypardiso installed or with MKL's library that cannot
        load (the message names the variable or argument, and the loader's error).
    """
    source = _source(backend)
    if backend is None:
        backend = os.environ.get("DEFOP_BACKEND", "").strip() or "auto"
    if not isinstance(backend, str) or backend.lower() not in BACKENDS:
        raise ValueError(f"{source} must be one of {', '.join(BACKENDS)}, got {backend!r:.80}")
    backend = backend.lower()
    if backend == "pardiso" and not HAVE_PARDISO:
        raise ValueError(
            f"{source}='pardiso' needs pypardiso (MKL, x86-64): pip install 'defop[mkl]', or use qdldl or auto"
        )
    mkl_threads()  # a bad DEFOP_MKL_THREADS is refused when the solver is built, not at its first factorisation
    if backend == "pardiso" and mkl_error() is not None:
        raise ValueError(
            f"{source}='pardiso' but MKL's library cannot load ({mkl_error()}): reinstall it (pip install "
            f"'defop[mkl]'), point PYPARDISO_MKL_RT at libmkl_rt, or set {source}=qdldl (auto falls back to it "
            f"by itself)"
        )
    return backend


def mkl_threads():
    """MKL's thread count for PARDISO: ``DEFOP_MKL_THREADS`` (default 1), or a ValueError naming it."""
    return config.integer_setting("DEFOP_MKL_THREADS", 1, minimum=1, rule="a whole number of threads >= 1")


def pardiso_solver():
    """The PyPardisoSolver (MKL loaded) every :class:`PardisoLDL` copies, made once per process.

    Raises
    ------
    ImportError, OSError, AttributeError
        pypardiso's import or MKL's library fails to load (the same error on every later call; see
        :func:`mkl_error`).
    """
    if "solver" not in _MKL:
        if "error" in _MKL:
            raise _MKL["error"]
        # MKL's conditional numerical reproducibility: the same code path on every x86-64 CPU, so the same
        # minima bit for bit across machines (measured: 10% slower on a nut solve than MKL's own choice)
        os.environ.setdefault("MKL_CBWR", "COMPATIBLE")
        try:
            import pypardiso  # its import makes a solver: it loads libmkl_rt (ImportError or OSError without it)

            _MKL["solver"] = pypardiso.PyPardisoSolver(mtype=-2)
        except (ImportError, OSError, AttributeError) as exc:  # AttributeError: a libmkl_rt with no pardiso
            _MKL["error"] = exc
            raise
    return _MKL["solver"]


def mkl_error():
    """Why MKL PARDISO cannot run in this process (``"OSError: ..."``), or None when it loads (tried once)."""
    if not HAVE_PARDISO:
        return "pypardiso is not installed"
    try:
        pardiso_solver()
    except (ImportError, OSError, AttributeError) as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def _warn_fallback(source):
    """Warn once per process that ``auto`` factorises by qdldl because MKL cannot load."""
    if _MKL.get("warned"):
        return
    _MKL["warned"] = True
    silence = "set DEFOP_BACKEND=qdldl" if source == "DEFOP_BACKEND" else "pass backend='qdldl'"
    warnings.warn(
        f"{source}=auto: MKL's library cannot load ({mkl_error()}), so tet meshes from {PARDISO_MIN_VERTICES_3D} "
        f"vertices are factorised by qdldl instead of PARDISO, {FALLBACK_COST} (benchmarks/README.md). Reinstall "
        f"MKL (pip install 'defop[mkl]'), or {silence} to choose qdldl and silence this warning",
        RuntimeWarning,
        stacklevel=opt.user_stacklevel(),
    )


def choose_backend(backend, n_vertices, d):
    """The factorisation a mesh of ``n_vertices`` in ``d`` dimensions gets: "qdldl", "pardiso" or "splu".

    ``auto``: PARDISO when installed and d = 3 with at least :data:`PARDISO_MIN_VERTICES_3D` vertices, else
    qdldl; SuperLU only when qdldl is missing (it gives no inertia). Where pypardiso is installed but MKL's
    library cannot load, ``auto`` takes qdldl and warns once per process (RuntimeWarning, with the slowdown and
    ``DEFOP_BACKEND=qdldl`` to silence it).
    """
    source = _source(backend)
    backend = check_backend(backend)
    if backend == "auto":
        big3d = d == 3 and n_vertices >= PARDISO_MIN_VERTICES_3D
        backend = "pardiso" if big3d and HAVE_PARDISO else "qdldl"
        if backend == "pardiso" and mkl_error() is not None:
            _warn_fallback(source)
            backend = "qdldl"
    if backend == "qdldl" and qdldl is None:  # pragma: no cover - exercised only without the dependency
        backend = "splu"
    return backend


def _pardiso_release(ps, A):
    ps.set_phase(-1)
    ps._call_pardiso(A, np.zeros(A.shape[0]))


class PardisoLDL:
    """MKL PARDISO's symmetric-indefinite LDLᵀ (mtype −2, Bunch-Kaufman pivots) of one fixed sparsity pattern.

    The ordering and symbolic analysis (phase 11) run once; each :meth:`factor` is the numeric factorisation
    (phase 22), :meth:`solve` the substitutions (phase 33). Sylvester's law of inertia holds for the pivoted
    LDLᵀ, so :meth:`inertia` is the negative eigenvalue count MKL reports (iparm[22]), qdldl's negative pivots.
    PARDISO replaces a pivot below 1e-8·‖K‖ by ±1e-8·‖K‖ (iparm[9] = 8, the default) where qdldl would divide by
    it; the verification shifts the diagonal by more than that (``INERTIA_SHIFT``).

    MKL runs on ``DEFOP_MKL_THREADS`` threads (default 1: one solve per core is how training uses the machine,
    and one thread makes every factorisation reproducible), with ``MKL_CBWR=COMPATIBLE`` unless the environment
    sets it: the same arithmetic on every x86-64 CPU.

    Parameters
    ----------
    K : (N, N) scipy CSC matrix
        The upper triangle (the pattern of every later ``factor``).
    """

    def __init__(self, K):
        # a copy of the one PyPardisoSolver whose loaded MKL all share (finding and loading it takes about 0.7 s):
        # a fresh handle and parameters, the same library
        self._ps = copy.copy(pardiso_solver())
        self._ps.pt = np.zeros_like(self._ps.pt)
        self._ps.iparm = np.zeros(64, dtype=np.int32)
        self._ps.libmkl.MKL_Set_Num_Threads(ctypes.c_int(mkl_threads()))
        iparm = self._ps.iparm
        iparm[0], iparm[1], iparm[9], iparm[10], iparm[12], iparm[20] = 1, 2, 8, 0, 0, 1
        # PARDISO reads the upper triangle row by row: the CSR order of the CSC values, found once
        order = sp.csc_matrix((np.arange(K.nnz, dtype=float), K.indices, K.indptr), shape=K.shape).tocsr()
        order.sort_indices()
        self._order = order.data.astype(np.int64)
        self._A = sp.csr_matrix((K.data[self._order], order.indices, order.indptr), shape=K.shape)
        self._call(11, np.zeros(K.shape[0]))
        self._ok = False
        # PARDISO's factors live in MKL's memory, not Python's: release them (phase −1) when this object goes, or
        # at exit while the interpreter still runs (a __del__ at shutdown cannot call MKL any more)
        weakref.finalize(self, _pardiso_release, self._ps, self._A)

    def _call(self, phase, b):
        self._ps.set_phase(phase)
        return self._ps._call_pardiso(self._A, b)

    def factor(self, K):
        """Numeric factorisation of K (upper CSC, the pattern given at construction).

        A matrix PARDISO cannot factorise (NaN values, say) leaves no factorisation: :meth:`solve` then returns
        NaN, as qdldl's would, and the Newton stage reports a non-finite direction."""
        from pypardiso.pardiso_wrapper import PyPardisoError

        self._A.data[:] = K.data[self._order]
        try:
            self._call(22, np.zeros(K.shape[0]))
            self._ok = True
        except PyPardisoError:
            self._ok = False

    def solve(self, b):
        """K⁻¹ b from the last factorisation (NaN when it failed)."""
        if not self._ok:
            return np.full(np.shape(b), np.nan)
        return np.asarray(self._call(33, np.asfortranarray(b, dtype=float))).reshape(b.shape)

    def inertia(self):
        """Negative eigenvalues of the last factorised K (MKL's iparm[22]); None when it failed."""
        return int(self._ps.iparm[22]) if self._ok else None


def element_dofs(F, d):
    """(m, (d+1)·d) global dof of every element's local dof: local (d·i + c) -> d·F[t, i] + c."""
    return (d * F[:, :, None] + np.arange(d)).reshape(len(F), -1)


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
    """

    def __init__(self, mesh, free, backend=None):
        self.backend = choose_backend(backend, mesh.n_vertices, mesh.V.shape[1])
        F = mesh.F
        d = mesh.V.shape[1]
        k = F.shape[1] * d  # local dofs per element: (d+1)·d
        dofs = element_dofs(F, d)
        rows = np.repeat(dofs, k, axis=1).ravel()
        cols = np.tile(dofs, (1, k)).ravel()
        gmap = -np.ones(d * mesh.n_vertices, np.int64)
        gmap[free] = np.arange(len(free))
        r, c = gmap[rows], gmap[cols]
        keep = (r >= 0) & (c >= 0) & (r <= c)  # upper triangle of the free-free block
        self._keep = np.flatnonzero(keep)
        self.dofs = dofs
        nf = self.nf = len(free)
        uniq, self._inv = np.unique(c[keep] * nf + r[keep], return_inverse=True)  # column-major = CSC
        self._rows = (uniq % nf).astype(np.int32)
        self._ptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // nf, minlength=nf))]).astype(np.int32)
        self._nnz = len(uniq)
        self._diag = np.searchsorted(uniq, uniq[(uniq % nf) == (uniq // nf)])
        self._K = self._factor = self._slot = None
        #: "numba": :meth:`assemble` runs :func:`defop.variational.fused.scatter`; "numpy": the reference
        self.kernel = "numba"

    def __getstate__(self):
        return {**self.__dict__, "_K": None, "_factor": None, "_slot": None}

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

            data = np.empty(self._nnz)
            fused.scatter(W, lamA, self.slot, bool(project), data)
            return data
        if project:
            lamA = np.maximum(lamA, 0.0)
        K_loc = np.matmul(W * lamA[:, None, :], np.swapaxes(W, 1, 2))  # (m, (d+1)d, (d+1)d)
        return np.bincount(self._inv, weights=K_loc.reshape(-1)[self._keep], minlength=self._nnz)

    def matrix(self, data, rel_shift=0.0):
        """The upper-triangular CSC matrix with these values plus ``rel_shift`` · mean|diag| on the diagonal."""
        if self._K is None:  # the pattern is fixed: build the matrix once, then only overwrite its values
            self._K = sp.csc_matrix((data.copy(), self._rows, self._ptr), shape=(self.nf, self.nf))
        self._K.data[:] = data
        self._K.data[self._diag] += rel_shift * max(float(np.mean(np.abs(data[self._diag]))), 1e-300)
        return self._K

    def full(self, data):
        """The symmetric matrix (both triangles), CSC."""
        K = self.matrix(data).copy()
        return (K + sp.triu(K, 1).T).tocsc()

    def solve(self, data, b, rel_shift):
        """K⁻¹ b with K = ``matrix(data, rel_shift)``; factorises."""
        K = self.matrix(data, rel_shift)
        if self.backend == "splu":  # pragma: no cover - exercised only without qdldl
            lu = sla.splu((K + sp.triu(K, 1).T).tocsc(), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
            return lu.solve(b)
        if self.backend == "pardiso":
            if self._factor is None:
                self._factor = PardisoLDL(K)
            self._factor.factor(K)
            return self._factor.solve(b)
        if self._factor is None:
            self._factor = qdldl.Solver(K, upper=True)
        else:
            self._factor.update(K, upper=True)
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
        #: energies below this (1e-12 · area) count as zero in relative tests (ARAP and S-ARAP vanish at rest)
        self._energy_floor = 1e-12 * float(mesh.areas.sum())

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_biharmonic"] = None
        return state

    @property
    def dim(self) -> int:
        """d: 2 for triangles, 3 for tetrahedra."""
        return self.mesh.V.shape[1]

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

    def newton_direction(self, g_free, data, rel_shift=1e-10):
        """−K⁻¹ g on the free dofs. A tiny relative diagonal shift keeps the projected (PSD) Hessian definite;
        the exact Hessian may be indefinite: the caller checks that the direction descends."""
        return -self.hessian.solve(data, g_free, rel_shift)

    def full(self, p):
        """(n, d) field from free-dof values ``p`` (zero at the handles)."""
        P = np.zeros(self.dim * self.mesh.n_vertices)
        P[self.free] = p
        return P.reshape(-1, self.dim)

    # ------------------------------------------------------------------ starts
    def extend(self, displacement):
        """Biharmonic extension (n, d) of the unique handles' displacements (u, d): :func:`biharmonic_extension`."""
        if self._biharmonic is None:
            self._biharmonic = biharmonic_factors(self.mesh, self.free_vertices, self.handles)
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
    L = mesh.cotmatrix
    Minv = sp.diags(1.0 / mesh.mass_matrix.diagonal())
    Q = (L.T @ Minv @ L).tocsc()
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


def check_start(mesh, X0, energy):
    """A copy of the start X0 (n, d), or of the rest pose when None; ValueError if it is not a valid start.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X0 : (n, d) array-like or None
    energy : str
        A barrier energy (:func:`defop.variational.energies.is_barrier`) needs a start without flipped elements.
    """
    if X0 is None:
        return mesh.V.copy()
    X = opt.real_array("X0", X0).copy()
    if X.shape != mesh.V.shape:
        raise ValueError(f"X0 must have shape {mesh.V.shape}, got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError("X0 has NaN or infinite entries")
    if en.is_barrier(energy) and np.any(mesh.flipped(X)):
        bad = np.flatnonzero(mesh.flipped(X))
        raise ValueError(
            f"X0 has {len(bad)} flipped triangle(s) (first: triangle {int(bad[0])}); "
            f"the {energy} energy is a barrier and needs a flip-free start"
        )
    return X
