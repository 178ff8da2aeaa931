"""The factorisation back end of the reduced Hessian: which LDLᵀ a solver uses, and MKL PARDISO's wrapper.

The back end is chosen at run time (:func:`choose_backend`): ``DEFOP_BACKEND=auto|qdldl|pardiso`` or the solver's
``backend`` keyword. ``qdldl`` reuses the AMD ordering and the symbolic analysis across updates; scipy's SuperLU is
the fallback without qdldl. ``pardiso`` is MKL PARDISO through the optional ``pypardiso`` (the ``mkl`` extra, x86-64
only; pypardiso is BSD-3, MKL comes under Intel's Simplified Software Licence), a supernodal symmetric-indefinite
LDLᵀ whose inertia (iparm[22]) feeds the saddle verification like qdldl's negative pivots. ``auto`` takes PARDISO
for tetrahedral meshes of at least :data:`PARDISO_MIN_VERTICES_3D` vertices, where it wins
(``benchmarks/bench_factor.py --real``), and qdldl everywhere else (2D stays bit-for-bit). Where pypardiso is
installed but MKL's library cannot load, ``auto`` falls back to qdldl with one warning per process, and an explicit
``pardiso`` is a ValueError naming ``DEFOP_BACKEND`` or ``backend``.
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

from .. import config
from .. import options as opt

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
#: vertices (0.80x at 9,873) and ties at 30k under ``MKL_CBWR=COMPATIBLE``: on the 29,739-vertex aleph a
#: factorisation and solve cost 86 ms of CPU against qdldl's 87, eight fine training runs 14.2 against 14.8 CPU s
#: (1.04x; 1.23x under ``MKL_CBWR=AVX2``, which gives up the same minima on every x86-64 CPU). 2D keeps qdldl
#: (bit for bit)
PARDISO_MIN_VERTICES_3D = 1000


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
        iparm[17] = -1  # report the factor's nonzeros (:meth:`nonzeros`); a report only, the factors are the same
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

    def nonzeros(self):
        """Nonzeros of the factor (MKL's iparm[17], from the symbolic analysis)."""
        return int(self._ps.iparm[17])


#: ``DEFOP_REUSE=auto`` re-uses a factorisation (:func:`pcg`) on Newton systems of at least this many unknowns (free
#: dofs); None: at no size. Measured on the 29,739-vertex aleph (59,468 unknowns, one thread), a qdldl factorisation
#: costs 105 ms, its triangular solves 5.2 ms and a product with the Hessian 1.2 ms, so one CG step costs 1/10 to
#: 1/15 of a factorisation (under load the solves slow down more). Only the exact steps near the optimum (about 3 of
#: a solve's 10-30 Newton steps) precondition well (3-9 CG steps); elsewhere CG needs 10-40 and stalls. Training
#: 12 samples there (benchmarks/bench_training.py, rows ``reuse`` and ``auto``) re-used 29 of 450 factorisations
#: and cost 3% more CPU; on the 2,810-vertex aleph a re-use cost 20% more (bench_newton_policy.py). So ``auto``
#: factorises every step at every size measured; ``DEFOP_REUSE=on`` re-uses at any size
REUSE_MIN_UNKNOWNS = None
#: the re-used factorisation's CG stops at a relative residual ‖K p + g‖ ≤ rtol ‖g‖ (:func:`forcing`) of at least
#: REUSE_RTOL ...
REUSE_RTOL = 1e-6
#: ... and at most REUSE_LOOSE (far from the optimum, where λ²/2 > REUSE_LOOSE · E) ...
REUSE_LOOSE = 1e-6
#: ... within this many iterations, else the Hessian is factorised afresh
REUSE_MAX_ITER = 10
#: after this many stalls in a row (the Hessian changing too fast from step to step), a solve factorises every step
REUSE_STALLS = 2
#: ``DEFOP_REUSE``: "auto" (re-use from :data:`REUSE_MIN_UNKNOWNS` unknowns: never), "on" (always), "off" (never)
REUSE = ("auto", "on", "off")


def choose_reuse(n_unknowns, backend):
    """Whether a Newton system of ``n_unknowns`` re-uses a factorisation as a preconditioner (``DEFOP_REUSE``).

    Raises
    ------
    ValueError
        ``DEFOP_REUSE`` is not one of :data:`REUSE`.
    """
    mode = os.environ.get("DEFOP_REUSE", "").strip().lower() or "auto"
    if mode not in REUSE:
        raise ValueError(f"DEFOP_REUSE must be one of {', '.join(REUSE)}, got {mode!r:.80}")
    if backend == "splu":  # pragma: no cover - exercised only without qdldl (SuperLU's factor is not kept)
        return False
    big = REUSE_MIN_UNKNOWNS is not None and n_unknowns >= REUSE_MIN_UNKNOWNS
    return mode == "on" or (mode == "auto" and big)


def forcing(rel_dec):
    """The relative residual a re-used factorisation's CG solves to, from the last relative Newton decrement
    λ²/2 / E: between :data:`REUSE_RTOL` and :data:`REUSE_LOOSE` (inexact Newton: a loose direction far from
    the optimum, an accurate one near it)."""
    return min(REUSE_LOOSE, max(REUSE_RTOL, float(rel_dec)))


def pcg(K, b, precondition, rtol=None, maxiter=None):
    """Preconditioned conjugate gradients on the symmetric K given by its upper triangle (CSC).

    Parameters
    ----------
    K : (N, N) scipy CSC matrix
        The upper triangle.
    b : (N,) numpy array
    precondition : callable
        ``precondition(r) -> M⁻¹ r``: the substitutions of an earlier factorisation.
    rtol, maxiter : float, int, optional
        Stop once ‖b − K x‖ ≤ ``rtol`` ‖b‖ (default :data:`REUSE_RTOL`); give up after ``maxiter`` iterations
        (default :data:`REUSE_MAX_ITER`).

    Returns
    -------
    found : tuple or None
        ``(x, iterations)``, or None on a stall: no convergence within ``maxiter`` iterations, a direction of
        non-positive curvature (K or the preconditioner indefinite) or a non-finite value.
    """
    rtol = REUSE_RTOL if rtol is None else rtol
    maxiter = REUSE_MAX_ITER if maxiter is None else maxiter
    d = K.diagonal()
    Kt = K.T  # CSR view of the lower triangle, no copy

    def A(x):
        return K @ x + Kt @ x - d * x

    x = np.zeros_like(b)
    r = b.copy()
    z = precondition(r)
    p = z.copy()
    rz = float(r @ z)
    bound = rtol * float(np.linalg.norm(b))
    for k in range(maxiter):
        Ap = A(p)
        pAp = float(p @ Ap)
        if not (pAp > 0 and rz > 0 and np.isfinite(pAp)):
            return None
        a = rz / pAp
        x += a * p
        r -= a * Ap
        if np.linalg.norm(r) <= bound:
            return x, k + 1
        z = precondition(r)
        rz_new = float(r @ z)
        p = z + (rz_new / rz) * p
        rz = rz_new
    return None
