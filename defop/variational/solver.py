"""The variational DefOp D^E: minimise a deformation energy subject to point-handle constraints.

Problem (6) of the paper: min_X E(X) = Σ_t A_t ψ(J_t(X)) subject to X[handles] = targets, over
piecewise-linear maps X (n,2). :class:`Solver` precomputes everything that depends only on the
mesh, the handle set and the energy, then solves by projected Newton:

* handles are hard constraints, eliminated from the system (only free vertices are unknowns);
* the Hessian Σ_t A_t B_tᵀ H_t B_t (H_t the PSD-projected Hessian of :mod:`defop.variational.energies`) is
  assembled into a fixed sparsity pattern, so only its values change between iterations;
* it is factorised with QDLDL (an LDLᵀ whose AMD ordering and symbolic analysis are computed
  once per Solver and reused by ``update`` in every iteration and every solve: 2 ms instead of
  10–17 ms for SuperLU on the aleph; scipy's ``splu`` is the fallback when qdldl is missing);
* once the decrement is small (λ²/2 ≤ 1e-2·E) the exact Hessian replaces the projected one while
  it gives a descent direction: the clamped eigenvalues make projected Newton converge only
  linearly near the optimum (aleph, warm S-ARAP solve: 28 → 6 iterations);
* one line search (:func:`line_search`, shared with :func:`solve_lbfgs`): for the barrier energies
  (S-ARAP, isometric) the step is first capped by the flip-free maximum step of Smith & Schaefer
  (2015), so no triangle ever flips, then Armijo backtracking;
* S-ARAP's kink (Eq. 11 is not differentiable on conformal Jacobians) is smoothed by μ for the first
  Newton stages; the last stage always minimises Eq. (11) itself (μ = 0).

``converged`` means a **verified local minimum** (:meth:`Solver.verify`), checked at the returned X
after the handles are written onto their targets: (1) the energy is finite; (2) every handle sits on
its target to 1e-12 of the bounding-box diagonal; (3) for barrier energies, no triangle is flipped or
collapsed; (4) the Newton decrement of the true energy (Eq. 10 / 11, μ = 0; at S-ARAP's kink, its conformal part) is
small, and no S-ARAP triangle held on the kink is pulled off it harder than its cone bears
(:meth:`Solver._kink_pull`, :func:`defop.variational.energies.kink_radius`); (5) the exact
reduced Hessian has no negative eigenvalue (beyond a 1e-8 relative shift), read from the inertia of its
LDLᵀ factorisation (Sylvester's law: the signs of D). ``reason`` names the check that failed.

A saddle is not an end state: when check (5) fails, the solve steps off along the most negative
curvature direction (Lanczos on the reduced Hessian, run only then), in both directions, continues
Newton from each and keeps the lower verified minimum. A point held on S-ARAP's kink that the mesh pulls
off it is left the same way, along the pull.

Starts: any flip-free map can warm-start a local solve (``X0``); its handles need not be at the
targets. From the start, the handles are moved to their targets through a biharmonic
extension of their displacement; for the barrier energies, if that would flip a triangle, the
handles are moved progressively (continuation), re-solving at each intermediate stage, halving
the stage length when a stage would flip. Every start handed to Newton is flip-free.
:meth:`Solver.solve_best` is the one multi-start policy: local solves from several starts (the rest
pose, a bootstrap prediction, a previous solution), keeping the lowest verified minimum;
``solve(..., start="global")`` uses it.

Baselines on the same energies: :func:`solve_lbfgs` (the paper's method, L-BFGS) and,
for ARAP, :func:`solve_libigl_arap` (libigl's local–global ARAP, ``ARAP_ENERGY_TYPE_ELEMENTS``).
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from .. import options as opt
from . import energies as en

try:  # QDLDL reuses the symbolic factorisation (AMD ordering, elimination tree) across updates
    import qdldl
except ImportError:  # pragma: no cover - exercised only without the dependency
    qdldl = None

#: bumped whenever a change to the solver moves its solutions (cache keys of ground truth should include it)
VERSION = 3
#: handles must sit on their targets to this fraction of the bounding-box diagonal (check 2)
HANDLE_TOL = 1e-12
#: targets farther than this many bounding-box diagonals from the mesh are rejected (the energy overflows)
MAX_TARGET_DISTANCE = 1e6
#: relative diagonal shift under which a negative Hessian eigenvalue counts as round-off (check 5)
INERTIA_SHIFT = 1e-8
#: S-ARAP triangles with Σ − σ ≤ KINK · Σ sit on Eq. (11)'s kink for check 4
#: (:func:`defop.variational.energies.eigensystem`)
KINK = 1e-4
#: at most this many triangles are released from the kink in one Newton solve (:meth:`Solver._kink_active_set`)
MAX_RELEASES = 64
#: ``"isometric_exp"`` only: a continuation stage whose start raises the largest log(1 + ψ) over the triangles by
#: more than this is halved like one that flips. Newton on ψ = exp(s·x) − 1 lowers the exponent by about one per
#: iteration, so a start at ψ ~ 1e259 (a full stage after a converged half stage, bar of 43 vertices) spent the whole
#: 300-iteration budget; a bound on the growth, not on ψ itself, still lets a huge stretch (ψ ~ 1e10 at the minimum)
#: converge
MAX_STAGE_GROWTH = {"isometric_exp": 20.0}


class NotConvergedWarning(RuntimeWarning):
    """A solve stopped before reaching a verified local minimum."""


@dataclasses.dataclass
class SolveResult:
    """Outcome of a solve.

    Attributes
    ----------
    X : (n,2) numpy array
        Deformed positions; ``X[handles] == targets``.
    energy : float
        Final E(X) (the true energy, Eq. 10 / 11).
    energy_history : (k,) numpy array
        E after each iteration (the start first).
    time_history : (k,) numpy array
        Seconds since the start of the solve at each entry of ``energy_history``.
    iterations : int
        Newton (or L-BFGS / local-global) iterations, continuation stages and escapes included.
    time : float
        Wall-clock seconds.
    converged : bool
        X is a verified local minimum (all five checks of :meth:`Solver.verify` pass).
    reason : str
        Why it stopped; when not converged, which check failed.
    flips : int
        Flipped or collapsed triangles in ``X``.
    start : str
        Which start the result came from: ``"X0"``, ``"rest"``, ``"start k"`` (k-th start given to
        :meth:`Solver.solve_best`), followed by ``" > escape +"`` / ``" > escape -"`` for each saddle escape
        and ``" > off kink"`` for each escape from S-ARAP's kink.
    candidates : list of tuple
        (start, energy, converged) of every local minimum or end point the solve reached, escapes and
        other starts included (the result itself is one of them).
    """

    X: np.ndarray
    energy: float
    energy_history: np.ndarray
    time_history: np.ndarray
    iterations: int
    time: float
    converged: bool
    reason: str
    flips: int = 0
    start: str = ""
    candidates: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class Verification:
    """Outcome of :meth:`Solver.verify`: ``ok``, the first failed check (``failed``, "" if none) and why."""

    ok: bool
    failed: str
    reason: str
    energy: float
    decrement: float = np.nan
    negative: int = 0
    #: check "kink" only: the (n,2) direction that pulls the overloaded triangles off Eq. (11)'s kink
    kink: np.ndarray | None = dataclasses.field(default=None, repr=False)


def count_flips(mesh, X):
    """Number of triangles with det J ≤ 0 (flipped or collapsed).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array

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
        Order is kept; duplicates are allowed (:meth:`Solver.targets_of` checks their targets agree).

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


def check_targets(targets, handles, mesh=None):
    """Validate targets: one finite row per handle, not absurdly far from the mesh.

    Parameters
    ----------
    targets : (h,2) array-like
    handles : (h,) int numpy array
    mesh : defop.geometry.mesh.Mesh, optional
        When given, targets farther than ``MAX_TARGET_DISTANCE`` bounding-box diagonals from the mesh's
        centre are rejected (the energy would overflow to inf: e.g. a target at 1e300).

    Returns
    -------
    T : (h,2) float numpy array
    """
    T = opt.real_array("targets", targets)
    if T.shape != (len(handles), 2):
        raise ValueError(f"targets must have shape ({len(handles)}, 2), one row per handle, got {T.shape}")
    if not np.isfinite(T).all():
        k = int(np.argwhere(~np.isfinite(T))[0, 0])
        raise ValueError(f"target {k} of handle vertex {int(handles[k])} is not finite: {T[k]}")
    if mesh is not None:
        d = mesh.bbox_diagonal
        far = np.abs(T - mesh.V.mean(axis=0)).max(axis=1) / d  # max-norm: no overflow at 1e300
        if far.max() > MAX_TARGET_DISTANCE:
            k = int(np.argmax(far))
            raise ValueError(
                f"target {k} of handle vertex {int(handles[k])} is {far[k]:.3g} bounding-box diagonals from the "
                f"mesh (more than {MAX_TARGET_DISTANCE:g}): the energy would overflow"
            )
    return T


def line_search(fun, X, P, E, slope, mesh=None, min_step=1e-12, c=1e-4):
    """Armijo backtracking along P, first capped by the flip-free maximum step when ``mesh`` is given.

    The one line search of :class:`Solver` (Newton) and :func:`solve_lbfgs`.

    Parameters
    ----------
    fun : callable
        ``fun(X) -> tuple`` whose first entry is the energy to decrease (further entries are passed back).
    X, P : (n,2) numpy arrays
        Current point (flip-free for a barrier energy) and search direction.
    E : float
        ``fun(X)[0]``.
    slope : float
        Directional derivative gᵀp < 0.
    mesh : defop.geometry.mesh.Mesh, optional
        Barrier energies: cap the step at :func:`defop.variational.energies.max_flip_free_step`.
    min_step : float
        Give up below this step.
    c : float
        Armijo constant.

    Returns
    -------
    found : tuple or None
        ``(step, X + step·P, fun(X + step·P))``, or None when no step ≥ ``min_step`` decreases enough.
    """
    step = 1.0
    if mesh is not None:
        step = en.max_flip_free_step(mesh.jacobians(X), mesh.jacobians(P))
    while step >= min_step:
        Xn = X + step * P
        val = fun(Xn)
        if val[0] <= E + c * step * slope:
            return step, Xn, val
        step *= 0.5
    return None


class _ReducedHessian:
    """The Hessian on the free dofs: a fixed sparsity pattern, assembly, an LDLᵀ and its inertia.

    The upper triangle of the free-free block is assembled in CSC order (QDLDL's input), so only its values
    change between iterations; QDLDL computes the AMD ordering and the symbolic analysis once and reuses them
    in every ``update``. Without qdldl, SuperLU (no inertia).
    """

    def __init__(self, mesh, free):
        F = mesh.F
        m = len(F)
        dofs = np.stack([2 * F, 2 * F + 1], axis=-1).reshape(m, 6)  # local dof 2i+c -> global
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        gmap = -np.ones(2 * mesh.n_vertices, np.int64)
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
        self._K = self._qdldl = None

    def __getstate__(self):
        return {**self.__dict__, "_K": None, "_qdldl": None}

    def assemble(self, local, project=True):
        """Values in the pattern from per-triangle modes W (m,6,4) and A_t·λ (m,4); ``project`` clamps the
        element eigenvalues at 0 (the PSD projection)."""
        W, lamA = local
        if project:
            lamA = np.maximum(lamA, 0.0)
        K_loc = np.matmul(W * lamA[:, None, :], np.swapaxes(W, 1, 2))  # (m,6,6)
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
        if qdldl is None:  # pragma: no cover - exercised only without the dependency
            self._qdldl = None
            lu = sla.splu((K + sp.triu(K, 1).T).tocsc(), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))
            return lu.solve(b)
        if self._qdldl is None:
            self._qdldl = qdldl.Solver(K, upper=True)
        else:
            self._qdldl.update(K, upper=True)
        return self._qdldl.solve(b)

    def inertia(self):
        """Negative pivots of the last LDLᵀ (Sylvester: negative eigenvalues of the shifted K), None without qdldl."""
        return None if self._qdldl is None else int(np.count_nonzero(self._qdldl.factors()[1] < 0))


class _Log:
    """Iteration budget and energy/time history shared by the stages of one solve."""

    def __init__(self, budget):
        self.budget = budget
        self.iters = 0
        self.t0 = time.perf_counter()
        self.E, self.t = [], []
        self.candidates = []

    @property
    def exhausted(self):
        return self.iters >= self.budget

    def record(self, E):
        self.E.append(E)
        self.t.append(time.perf_counter() - self.t0)


class Solver:
    """Projected-Newton solver of problem (6) on one mesh, one handle set and one energy.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array or (n_vertices,) bool numpy array
        Constrained vertices (moving and fixed handles), in any order (see :func:`check_handles`).
        Targets are always given in this order. A vertex listed twice must get the same target each time.
    energy : str
        ``"arap"`` (Eq. 10), ``"sarap"`` (Eq. 11), ``"isometric"`` (symmetric Dirichlet), ``"isometric_max"``
        or ``"isometric_exp"`` (see :data:`defop.variational.energies.ENERGIES`).
    tol : float
        Default tolerance: Newton stops at a decrement λ²/2 ≤ tol · E (check 4 uses ``verify_tol``).
    max_iter : int
        Default iteration limit (continuation stages and saddle escapes included).
    smoothing : tuple of float, optional
        S-ARAP only: the μ of the smoothed kink (:func:`defop.variational.energies.psi_sarap_smooth`), one Newton stage
        per entry. A final μ = 0 stage (Eq. 11 itself) is always appended: default ``(1e-5, 0)``. Measured on
        4 problems each on the aleph and the gingerbread man (moves of 5% of the diagonal, against a
        μ → 1e-13 reference), a μ = 1e-5 optimum alone sits up to 3.9e-6 (relative energy) above Eq. (11)'s
        minimum and 3.7e-5 of the diagonal away from it; the default ends within 2.3e-8 of it (0-3 more
        iterations), ``(1e-5, 1e-7, 0)`` within 2e-9 (up to 5 more). The μ = 0 stage treats triangles on the
        kink as check 4 does (below); without that it stalls 2.6e-7 above the minimum.

    Attributes
    ----------
    handles : (u,) int numpy array
        The unique handle vertices, sorted. ``handles_given`` keeps the order of the constructor.
    verify_tol : float
        Check 4: the true energy's Newton decrement λ²/2 ≤ verify_tol · E (default 1e-6; Newton itself stops
        at ``tol``). Eq. (11) is not differentiable on its kink: S-ARAP triangles within ``KINK`` (1e-4,
        relative) of Σ = σ count as sitting on it, with the conformal part of their gradient and stiff
        anti-conformal modes (:func:`defop.variational.energies.eigensystem`, ``kink``); the μ = 0 Newton stage uses the
        same rule, so it stops on this decrement, normally at ``tol``. Without the rule the decrement of
        Eq. (11) stayed up to 1.4e-6 · E (3.4e-5 · E on the bar) at energies converged to 1e-9. A held triangle
        must also be in equilibrium on the cone: check 4 fails ("kink") when the force pulling it off exceeds
        what the cone bears by a bound on the gain above ``verify_tol`` · E; it passed a point 1.6e-5 · E above
        a nearby minimum before (star seed 3273, one triangle pulled at 1.083 times its cone's force).

    Notes
    -----
    Newton starts with the PSD-projected Hessian and switches to the exact one once the decrement is
    below ``exact_switch``·E (1e-2) — quadratic instead of linear convergence near the optimum — falling
    back to the projected Hessian whenever the exact direction does not descend or needs a step
    below 1e-3.

    Instances are picklable (for joblib); the factorisation is rebuilt after unpickling.
    """

    def __init__(self, mesh, handles, energy="sarap", tol=1e-9, max_iter=300, smoothing=None):
        self.mesh = mesh
        self.energy = en.check_energy(energy)
        self.barrier = en.is_barrier(energy)
        self.handles_given = check_handles(mesh, handles)
        #: unique sorted handle vertices; ``targets_given[k]`` belongs to ``handles[_slot[k]]``
        self.handles, self._slot = np.unique(self.handles_given, return_inverse=True)
        self.tol = check_tol(tol)
        self.max_iter = check_max_iter(max_iter)
        n = mesh.n_vertices
        if len(self.handles) == n:
            raise ValueError(f"every one of the {n} vertices is a handle: there is nothing to solve for")
        is_handle = np.zeros(n, bool)
        is_handle[self.handles] = True
        self.free_vertices = np.flatnonzero(~is_handle)
        self.free = np.column_stack([2 * self.free_vertices, 2 * self.free_vertices + 1]).ravel()
        self._hess = _ReducedHessian(mesh, self.free)
        self._biharmonic = None
        self.mu_schedule = (0.0,)
        if self.energy == "sarap":
            mus = (1e-5,) if smoothing is None else tuple(check_tol(m, "smoothing μ") for m in smoothing)
            if not mus:
                raise ValueError(f"smoothing must be a non-empty sequence of μ >= 0, got {smoothing!r}")
            self.mu_schedule = mus if mus[-1] == 0 else mus + (0.0,)
        self.verify_tol = 1e-6
        #: the μ = 0 stage and check 4 treat S-ARAP triangles within KINK of Σ = σ as on the kink
        self._kink = KINK
        #: energies below this (1e-12 · area) count as zero in relative tests (ARAP and S-ARAP vanish at rest)
        self._energy_floor = 1e-12 * float(mesh.areas.sum())
        #: switch from the projected to the exact Hessian once λ²/2 ≤ exact_switch · E
        self.exact_switch = 1e-2
        #: tolerance of the intermediate μ stages: from a loosely converged stage, Newton on the next, sharper
        #: kink (curvature ~ 1/μ) crawls with tiny steps (measured: stage tolerance 1e-4 took up to 0.80 s on
        #: the gingerbread man where 1e-8 took 0.08 s)
        self.stage_tol = 1e-8
        #: saddle escapes per solve (each tries both directions)
        self.max_escapes = 4

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_biharmonic"] = None
        return state

    # ------------------------------------------------------------------ targets
    def targets_of(self, targets):
        """Validate targets given in the constructor's handle order; return them per unique handle.

        Parameters
        ----------
        targets : (h,2) array-like
            One row per entry of the ``handles`` given to the constructor.

        Returns
        -------
        T : (u,2) numpy array
            ``T[j]`` is the target of vertex ``self.handles[j]``.
        """
        Tg = check_targets(targets, self.handles_given, self.mesh)
        T = np.empty((len(self.handles), 2))
        T[self._slot] = Tg
        bad = np.flatnonzero(np.abs(Tg - T[self._slot]).max(axis=1) > 1e-12 * self.mesh.bbox_diagonal)
        if len(bad):
            k = int(bad[0])
            v = int(self.handles_given[k])
            raise ValueError(
                f"vertex {v} is given two different targets: {T[self._slot[k]].tolist()} and {Tg[k].tolist()}"
            )
        return T

    # ------------------------------------------------------------------ energy pieces
    def energy_of(self, X, mu=0.0):
        """E(X) (+inf for a flipped triangle under a barrier energy); ``mu`` smooths S-ARAP's kink."""
        return en.total_energy(self.mesh, X, self.energy, mu)

    def _energies(self, X, mu):
        """(E_μ(X), E(X)): the smoothed energy Newton minimises and the true one, from one SVD."""
        if not mu:
            E = self.energy_of(X)
            return E, E
        S = en.svd_frame(self.mesh.jacobians(X))[0]
        smooth, exact = en.psi_value(self.energy, S[:, 0], S[:, 1], mu, both=True)
        return float(self.mesh.areas @ smooth), float(self.mesh.areas @ exact)

    def _grad_hess(self, X, mu=0.0, project=True, kink=0.0):
        """E, the gradient (2n,) and the Hessian values in the fixed upper-triangular CSC pattern.

        Per triangle, K_t = A_t Σ_k λ_k w_k w_kᵀ with w_k = B_tᵀ vec(M_k) for the eigenpairs (λ_k, M_k)
        of :func:`defop.variational.energies.eigensystem`: no 4×4 Hessian is formed. Also returns ``local``, with
        which :meth:`_ReducedHessian.assemble` rebuilds the projected Hessian without a second eigensystem.
        """
        mesh = self.mesh
        G = mesh.jacobian_operator
        J = (G @ np.asarray(X, dtype=float).ravel()).reshape(-1, 2, 2)
        psi, grad, lam, modes = en.eigensystem(J, self.energy, project=False, mu=mu, kink=kink)
        A = mesh.areas
        E = float(A @ psi)
        g = G.T @ (A[:, None] * grad).ravel()
        D = mesh.local_gradients  # (m,3,2)
        m = len(D)
        # w_k[2i+a] = Σ_b ∇φ_i[b] M_k[a,b]: one (3,2)@(2,8) product per triangle
        Mb = np.ascontiguousarray(modes.reshape(m, 2, 2, 4).transpose(0, 2, 1, 3)).reshape(m, 2, 8)
        local = (np.matmul(D, Mb).reshape(m, 6, 4), lam * A[:, None])
        return E, g, self._hess.assemble(local, project), local

    def _newton_direction(self, g_free, data, rel_shift=1e-10):
        # a tiny relative diagonal shift keeps the projected (PSD) Hessian definite; the exact Hessian
        # may be indefinite: the caller checks that the direction descends
        return -self._hess.solve(data, g_free, rel_shift)

    def _full(self, p):
        """(n,2) field from free-dof values ``p`` (zero at the handles)."""
        P = np.zeros(2 * self.mesh.n_vertices)
        P[self.free] = p
        return P.reshape(-1, 2)

    # ------------------------------------------------------------------ starts
    def _biharmonic_solver(self):
        if self._biharmonic is None:
            L = self.mesh.cotmatrix
            Minv = sp.diags(1.0 / self.mesh.mass_matrix.diagonal())
            Q = (L.T @ Minv @ L).tocsc()
            fv, hv = self.free_vertices, self.handles
            self._biharmonic = (sla.splu(Q[fv][:, fv].tocsc()), Q[fv][:, hv].tocsc())
        return self._biharmonic

    def extend(self, displacement):
        """Biharmonic extension of handle displacements to the whole mesh.

        Parameters
        ----------
        displacement : (u,2) numpy array
            Displacement of each unique handle vertex, in the order of ``self.handles`` (sorted).

        Returns
        -------
        D : (n,2) numpy array
            Zero-Laplacian-squared displacement field equal to ``displacement`` at the handles.
        """
        lu, Qfh = self._biharmonic_solver()
        D = np.zeros((self.mesh.n_vertices, 2))
        D[self.handles] = displacement
        D[self.free_vertices] = -lu.solve(np.asarray(Qfh @ displacement))
        return D

    def _check_start(self, X0):
        if X0 is None:
            return self.mesh.V.copy()
        X = opt.real_array("X0", X0).copy()
        if X.shape != self.mesh.V.shape:
            raise ValueError(f"X0 must have shape {self.mesh.V.shape}, got {X.shape}")
        if not np.isfinite(X).all():
            raise ValueError("X0 has NaN or infinite entries")
        if self.barrier and np.any(self.mesh.flipped(X)):
            bad = np.flatnonzero(self.mesh.flipped(X))
            raise ValueError(
                f"X0 has {len(bad)} flipped triangle(s) (first: triangle {int(bad[0])}); "
                f"the {self.energy} energy is a barrier and needs a flip-free start"
            )
        return X

    # ------------------------------------------------------------------ solve
    def solve(self, targets, X0=None, tol=None, max_iter=None, max_stages=64, start="local"):
        """Minimise the energy with the handles at ``targets``; ``converged`` means a verified local minimum.

        Parameters
        ----------
        targets : (h,2) numpy array
            Target positions, one row per entry of ``handles`` given to the constructor (in that order).
        X0 : (n,2) numpy array, optional
            Start (any map; flip-free for a barrier energy). Its handle rows need not be at the
            targets. Default: the rest pose.
        tol : float, optional
            Newton-decrement tolerance relative to the energy (default ``self.tol``).
        max_iter : int, optional
            Iteration limit (default ``self.max_iter``).
        max_stages : int
            Limit on continuation stages for far moves.
        start : {"local", "global"}
            ``"local"``: one path from ``X0`` (warm start, path following; saddles are still escaped).
            ``"global"``: :meth:`solve_best` from the rest pose and ``X0`` (when given), the lower
            verified minimum. This is a documented multi-start, not a certificate: where the energy has
            several minima it can miss a lower one that no start leads to (a stranger's test found an
            ARAP bar pushed 0.35 along its axis whose up-bent start verified at 3% lower energy).

        Returns
        -------
        result : SolveResult
            ``converged`` is False (and a :class:`NotConvergedWarning` is issued) when a check of
            :meth:`verify` fails or the iteration limit was hit; ``reason`` says which.

        Raises
        ------
        ValueError
            Targets of the wrong shape, not finite or absurdly far, a vertex with two different
            targets, an invalid ``tol``/``max_iter``, or a flipped start for a barrier energy.
        """
        if start == "global":
            return self.solve_best(targets, starts=() if X0 is None else (X0,), tol=tol, max_iter=max_iter)
        if start != "local":
            raise ValueError(f"start must be 'local' or 'global', got {start!r}")
        result = self._local(targets, X0, tol, max_iter, max_stages, "rest" if X0 is None else "X0")
        if not result.converged:
            warnings.warn(f"{self.energy} solve did not converge: {result.reason}", NotConvergedWarning, stacklevel=2)
        return result

    def _local(self, targets, X0, tol, max_iter, max_stages, label):
        """One local solve (continuation, Newton, saddle escapes), verified; no warning."""
        tol = self.tol if tol is None else check_tol(tol)
        log = _Log(self.max_iter if max_iter is None else check_max_iter(max_iter))
        T = self.targets_of(targets)
        X = self._check_start(X0)
        X, reached, reason, ok = self._continuation(log, X, T, tol, max_stages)
        check = None
        if reached:
            X, label, reason, ok, check = self._escape(log, X, T, tol, label, reason, ok, self.max_escapes)
        else:
            log.candidates.append((label, self.energy_of(X), False))
        return self._result(log, X, T, reason, label, ok and reached, check)

    def _result(self, log, X, T, reason, label, ok, check=None):
        check = self.verify(X, T) if check is None else check
        converged = bool(ok and check.ok)
        if not check.ok:
            reason = f"{reason}; check failed: {check.reason}"
        return SolveResult(
            X=X,
            energy=check.energy,
            energy_history=np.array(log.E),
            time_history=np.array(log.t),
            iterations=log.iters,
            time=time.perf_counter() - log.t0,
            converged=converged,
            reason=reason,
            flips=count_flips(self.mesh, X),
            start=label,
            candidates=list(log.candidates),
        )

    def _continuation(self, log, X, T, tol, max_stages):
        """Move the handles from X's to T (barrier energies: in flip-free stages), Newton at each stage.

        Returns (X, reached, reason, ok): ``reached`` is False when the handles could not be moved all the way,
        ``ok`` whether the last Newton stage met its tolerance.
        """
        mesh = self.mesh
        start_h = X[self.handles].copy()
        s, frac, stages = 0.0, 1.0, 0
        reason = ""
        while s < 1.0:
            if stages >= max_stages:
                return X, False, f"continuation needed more than {max_stages} stages", False
            s_next = min(1.0, s + frac)
            Xt = X + self.extend((s_next - s) * (T - start_h))
            if (self.barrier and np.any(mesh.flipped(Xt))) or self._too_steep(X, Xt):
                frac /= 2
                if frac < 1e-6:
                    return X, False, "could not move the handles without flipping a triangle", False
                continue
            stages += 1
            Xt[self.handles] = start_h + s_next * (T - start_h)
            if self.barrier and s_next >= 1.0 and np.any(mesh.flipped(Xt)):
                return X, False, "the targets collapse or flip a triangle between handles", False
            s = s_next
            X, converged, reason = self._newton(log, Xt, tol if s >= 1.0 else max(tol, 1e-4))
            if log.exhausted and not converged:
                return X, s >= 1.0, reason, False
            frac = min(1.0 - s, 2 * frac) if s < 1.0 else frac
        if stages > 1:
            reason += f" (after {stages} continuation stages)"
        return X, True, reason, converged

    def _too_steep(self, X, Xt):
        """Whether a stage from X to Xt raises the largest log(1 + ψ) by more than :data:`MAX_STAGE_GROWTH`."""
        grow = MAX_STAGE_GROWTH.get(self.energy)
        if grow is None:
            return False
        top = [np.log1p(en.density(self.mesh.jacobians(Y), self.energy).max()) for Y in (X, Xt)]
        return not top[1] - top[0] <= grow

    def _newton(self, log, X, tol):
        """Newton at fixed handles; S-ARAP runs through its smoothing schedule, ending on Eq. (11) itself."""
        for i, mu in enumerate(self.mu_schedule):
            last = i == len(self.mu_schedule) - 1
            if last and self.energy == "sarap":
                return self._kink_active_set(log, X, tol)
            X, converged, reason = self._newton_stage(log, X, tol if last else max(tol, self.stage_tol), mu)
            if log.exhausted:
                break
        return X, converged, reason

    def _kink_active_set(self, log, X, tol):
        """Newton on Eq. (11) (μ = 0) with an active set of triangles held on its kink.

        Triangles on the kink (:func:`defop.variational.energies.on_kink`) are held there; once Newton has converged, a
        held triangle that the mesh pulls off harder than its cone bears (:meth:`_kink_pull`) is released: the
        solve steps along the pull (a line search on the true energy) and Newton continues without holding it.
        Returns (X, converged, reason) like :meth:`_newton_stage`.
        """
        hold = np.full(len(self.mesh.F), self._kink)
        released = 0
        while True:
            X, converged, reason = self._newton_stage(log, X, tol, 0.0, hold)
            if not converged or log.exhausted or released >= MAX_RELEASES:
                return X, converged, reason
            E, g, data, local = self._grad_hess(X, 0.0, project=False, kink=hold)
            p = self._newton_direction(g[self.free], data, rel_shift=INERTIA_SHIFT)
            gain, _, D, pulled = self._kink_pull(X, local, p, hold)
            Xs = None if gain <= tol * max(E, self._energy_floor) else self._step_off(X, D)
            if Xs is None:
                return X, converged, reason + (f" ({released} triangle(s) released from the kink)" if released else "")
            hold[pulled] = -1.0  # never on the kink again in this solve
            released += len(pulled)
            X = Xs

    def _newton_stage(self, log, X, tol, mu, hold=None):
        """Projected (then exact) Newton on E_μ from a flip-free X. Returns (X, converged, reason).

        ``hold``: S-ARAP at μ = 0, the per-triangle kink thresholds (default ``KINK``; see :func:`on_kink`)."""
        hold = self._kink if hold is None else hold
        E, E_true = self._energies(X, mu)
        log.record(E_true)
        stalls, rel_dec, exact_ok = 0, np.inf, True
        fun = (lambda Y: self._energies(Y, mu)) if mu else (lambda Y: (self.energy_of(Y), None))
        while True:
            if log.exhausted:
                return X, False, f"iteration limit {log.budget} reached"
            exact = exact_ok and rel_dec <= self.exact_switch
            # near the optimum the exact Hessian converges quadratically where the projected one (clamped
            # element eigenvalues) converges only linearly; use it while it descends
            E, g, data, local = self._grad_hess(X, mu, project=not exact, kink=0.0 if mu else hold)
            gf = g[self.free]
            p = self._newton_direction(gf, data)
            dec = -float(gf @ p)  # Newton decrement λ²
            if exact and not (np.isfinite(dec) and dec > 0):
                exact = False  # indefinite: fall back to the projected Hessian, same eigensystem
                p = self._newton_direction(gf, self._hess.assemble(local))
                dec = -float(gf @ p)
            if not np.isfinite(E):
                return X, False, "the energy is not finite (a collapsed triangle)"
            if not np.isfinite(dec):
                return X, False, "Newton direction is not finite (degenerate Hessian)"
            rel_dec = dec / 2 / max(E, self._energy_floor)
            if dec / 2 <= tol * max(E, self._energy_floor):
                return X, True, f"Newton decrement λ²/2 = {dec / 2:.2e} <= tol·E"
            mesh = self.mesh if self.barrier else None
            found = line_search(fun, X, self._full(p), E, -dec, mesh, min_step=1e-3 if exact else 1e-12)
            if found is None and exact:  # the exact Hessian's model is poor here: back to the projected one
                exact_ok = False
                continue
            log.iters += 1
            if found is None:
                log.record(self.energy_of(X))
                ok = dec / 2 <= 1e-6 * max(E, self._energy_floor)  # at round-off: as good as it gets
                return X, ok, "line search stalled at round-off" if ok else "line search failed"
            step, X, (En, En_true) = found
            log.record(En if En_true is None else En_true)
            if exact and step == 1.0 and dec / 2 <= 10 * tol * max(E, self._energy_floor):
                # a full exact Newton step from λ²/2 ≤ 10·tol·E lands within O(λ⁴) of the optimum
                return X, True, f"full Newton step from λ²/2 = {dec / 2:.2e} <= 10·tol·E"
            # triangles on S-ARAP's kink make the last digits converge linearly: three steps in a row that
            # each gain less than tol·E mean the energy has converged
            stalls = stalls + 1 if E - En <= tol * E else 0
            if stalls >= 3:
                return X, True, f"energy stagnated: 3 steps each reduced E by <= {tol:g}·E"

    # ------------------------------------------------------------------ verification and saddles
    def verify(self, X, T, tol=None):
        """The five checks behind ``converged``, at X (handles already on their targets).

        Parameters
        ----------
        X : (n,2) numpy array
        T : (u,2) numpy array
            Targets per unique handle (:meth:`targets_of`).
        tol : float, optional
            Check 4's tolerance (default ``verify_tol``).

        Returns
        -------
        check : Verification
            ``failed`` is one of "energy", "handles", "flips", "saddle", "decrement", "kink" (or "").
        """
        tol = self.verify_tol if tol is None else tol
        mesh = self.mesh
        E = self.energy_of(X)
        flips = count_flips(mesh, X)
        if not np.isfinite(E):
            return Verification(
                False, "energy", f"energy is not finite (E = {E}, {flips} flipped/collapsed triangles)", E
            )
        err = float(np.abs(X[self.handles] - T).max()) / mesh.bbox_diagonal
        if not err <= HANDLE_TOL:
            return Verification(False, "handles", f"a handle is {err:.2e} of the diagonal off its target", E)
        if self.barrier and flips:
            return Verification(False, "flips", f"{flips} flipped or collapsed triangle(s)", E)
        E, g, data, local = self._grad_hess(X, 0.0, project=False, kink=self._kink)  # true energy, exact Hessian
        gf = g[self.free]
        p = self._newton_direction(gf, data, rel_shift=INERTIA_SHIFT)
        negative = self._hess.inertia()
        dec = -float(gf @ p) / 2
        if negative:
            why = f"saddle point: the reduced Hessian has {negative} negative eigenvalue(s)"
            return Verification(False, "saddle", why, E, dec, negative)
        if not (np.isfinite(dec) and dec <= tol * max(E, self._energy_floor)):
            why = f"the true energy's Newton decrement λ²/2 = {dec:.2e} > {tol:g}·E"
            return Verification(False, "decrement", why, E, dec)
        if self.energy == "sarap":
            gain, worst, D, _ = self._kink_pull(X, local, p, self._kink)
            if gain > tol * max(E, self._energy_floor):
                why = (
                    f"not a minimum at Eq. (11)'s kink: triangle {worst[0]} is pulled off it by {worst[1]:.4g} times "
                    f"the force its cone bears; moving off lowers E by up to {gain:.2e} > {tol:g}·E"
                )
                return Verification(False, "kink", why, E, dec, 0, D)
        return Verification(True, "", "", E, dec, 0)

    def _kink_pull(self, X, local, p, hold):
        """S-ARAP triangles held on Eq. (11)'s kink (check 4) that the rest of the mesh pulls off it.

        Check 4 holds a triangle on the kink (:func:`defop.variational.energies.on_kink`): its anti-conformal modes
        are stiff, so in
        the Newton system K p = −g their amplitudes times their stiffness are the force F_t the rest of the mesh
        puts on them. There ψ is a cone (:func:`defop.variational.energies.kink_radius`): the triangle is in equilibrium
        only if ‖F_t‖ ≤ A_t r_t. A triangle pulled harder moves off the kink, and the quadratic model with its
        own branch curvature κ_t bounds the gain by (‖F_t‖ − A_t r_t)² / (2 A_t κ_t) when the rest is convex.

        Returns
        -------
        gain : float
            Σ_t of that bound over the overloaded triangles (0 if none).
        worst : tuple
            (triangle, ‖F_t‖ / (A_t r_t)) of the largest bound.
        D : (n,2) numpy array or None
            Descent direction: each overloaded triangle's anti-conformal modes moved along its force, by the
            model's amplitude (‖F_t‖ − A_t r_t)/(A_t κ_t); zero at the handles.
        pulled : (k,) int numpy array
            The overloaded triangles.
        """
        S = en.svd_frame(self.mesh.jacobians(X))[0]
        on = np.flatnonzero(en.on_kink(S, hold))
        none = 0.0, None, None, on[:0]
        if not len(on):
            return none
        W, lamA = local[0][on][:, :, [1, 3]], local[1][on][:, [1, 3]]
        dofs = self._hess.dofs[on]
        amp = np.einsum("tdk,td->tk", W, self._full(p).ravel()[dofs])  # stiff-mode amplitudes of the step
        force = np.hypot(*(lamA * amp).T)
        A = self.mesh.areas[on]
        r, kappa = en.kink_radius(S[on])
        excess = np.maximum(force - A * r, 0.0)
        gains = excess**2 / (2 * A * kappa)
        if not gains.any():
            return none
        k = int(np.argmax(gains))
        u = amp * (excess / (A * kappa) / np.maximum(np.hypot(*amp.T), 1e-300))[:, None]
        D = np.bincount(dofs.ravel(), np.einsum("tdk,tk->td", W, u).ravel(), minlength=2 * self.mesh.n_vertices)
        D = D.reshape(-1, 2)
        D[self.handles] = 0.0
        return float(gains.sum()), (int(on[k]), float(force[k] / (A[k] * r[k]))), D, on[gains > 0]

    def negative_curvature(self, X):
        """The most negative eigenpair of the exact reduced Hessian of the true energy at X.

        Lanczos (ARPACK) on the free-free block; called only when the inertia showed a negative pivot.

        Returns
        -------
        lam : float
        D : (n,2) numpy array
            Unit eigenvector as a displacement field (zero at the handles).
        """
        data = self._grad_hess(X, 0.0, project=False)[2]
        K = self._hess.full(data)
        if K.shape[0] <= 400:
            lam, v = np.linalg.eigh(K.toarray())
            lam, v = lam[:1], v[:, :1]
        else:
            v0 = np.ones(K.shape[0]) / np.sqrt(K.shape[0])  # deterministic start vector
            lam, v = sla.eigsh(K, k=1, which="SA", v0=v0, tol=1e-6, maxiter=5000)
        return float(lam[0]), self._full(v[:, 0])

    def _step_off(self, X, D):
        """A flip-free point along D from the saddle X with lower energy, or None."""
        E = self.energy_of(X)
        step = 0.05 * self.mesh.bbox_diagonal / max(float(np.abs(D).max()), 1e-300)
        if self.barrier:
            step *= en.max_flip_free_step(self.mesh.jacobians(X), self.mesh.jacobians(step * D))
        for _ in range(40):
            Xs = X + step * D
            if self.energy_of(Xs) < E - 1e-12 * abs(E):
                return Xs
            step *= 0.5
        return None

    def _escape(self, log, X, T, tol, label, reason, ok, escapes):
        """Leave a point that is not a minimum and Newton on; keep the lower verified minimum.

        At a saddle, step off along the most negative curvature, both ways; at S-ARAP's kink (check "kink"),
        along the direction that pulls the overloaded triangles off it (:meth:`_kink_pull`).
        Returns (X, label, reason, ok, check) of the best end point (``check`` its :meth:`verify`).
        """
        check = self.verify(X, T)
        if check.failed not in ("saddle", "kink") or escapes == 0 or log.exhausted:
            log.candidates.append((label, check.energy, bool(ok and check.ok)))
            return X, label, reason, ok, check
        log.candidates.append((label, check.energy, False))
        if check.failed == "saddle":
            D = self.negative_curvature(X)[1]
            ways = ((D, "escape +"), (-D, "escape -"))
            left = f"a saddle with {check.negative} negative eigenvalue(s)"
        else:
            ways, left = ((check.kink, "off kink"),), "Eq. (11)'s kink, pulled off it"
        best = (X, label, reason, ok, check)
        best_key = (True, check.energy)
        for D, tag in ways:
            Xs = self._step_off(X, D)
            if Xs is None or log.exhausted:
                continue
            Xs, ok_s, why = self._newton(log, Xs, tol)
            why = f"{why} (escaped {left})"
            lab = f"{label} > {tag}"
            out = self._escape(log, Xs, T, tol, lab, why, ok_s, escapes - 1)
            key = (not (out[3] and out[4].ok), out[4].energy)
            if key < best_key:
                best, best_key = out, key
        return best

    # ------------------------------------------------------------------ the one multi-start policy
    def solve_best(self, targets, starts=(), rest=True, keep="lowest", tol=None, max_iter=None):
        """Local solves from several starts; the lowest-energy verified minimum (the one multi-start policy).

        Every local solve escapes saddles along negative curvature (both directions), so the candidates
        are: each given start, the rest pose (for barrier energies reached through flip-free continuation),
        and the escapes from any saddle on the way.

        Parameters
        ----------
        targets : (h,2) numpy array
            One row per handle given to the constructor.
        starts : sequence of (n,2) numpy arrays or None
            Extra starts (a bootstrap prediction, a previous solution); None entries are ignored, and
            starts that are flipped (barrier energies) or otherwise rejected are skipped.
        rest : bool
            Also solve from the rest pose (tried after ``starts``; also used when every start is rejected).
        keep : {"lowest", "first"}
            ``"lowest"``: run every start and keep the lowest verified minimum (global). ``"first"``: stop at
            the first start that yields a verified minimum (warm, path-following: the interactive editor).
        tol, max_iter : optional
            As in :meth:`solve` (``max_iter`` per start).

        Returns
        -------
        result : SolveResult
            ``start`` names the winning start (``"start k"`` or ``"rest"``, plus any escapes);
            ``candidates`` lists (start, energy, converged) for every end point reached.
        """
        if keep not in ("lowest", "first"):
            raise ValueError(f"keep must be 'lowest' or 'first', got {keep!r}")
        self.targets_of(targets)  # bad targets raise here, not once per start
        runs = [(f"start {k}", X0) for k, X0 in enumerate(starts) if X0 is not None]
        runs += [("rest", None)] if rest else []
        results, skipped = [], []
        for label, X0 in runs:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", NotConvergedWarning)
                    r = self.solve(targets, X0=X0, tol=tol, max_iter=max_iter)
            except ValueError as exc:  # a rejected start (flipped, wrong shape): the next one
                skipped.append((label, str(exc)))
                continue
            if X0 is not None:  # "X0 > escape ..." -> "start k > escape ..."
                r.start = label + r.start[2:]
                r.candidates = [(label + lab[2:], E, ok) for lab, E, ok in r.candidates]
            results.append(r)
            if keep == "first" and r.converged:
                break
        if not results:  # every given start was rejected (flipped): the rest pose is always a valid start
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotConvergedWarning)
                results.append(self.solve(targets, tol=tol, max_iter=max_iter))
        best = min(results, key=lambda r: (not r.converged, r.energy if np.isfinite(r.energy) else np.inf))
        best.candidates = [c for r in results for c in r.candidates] + [
            (f"{label} (rejected: {why})", np.inf, False) for label, why in skipped
        ]
        if not best.converged:
            warnings.warn(
                f"{self.energy} solve did not converge from any start: {best.reason}", NotConvergedWarning, stacklevel=2
            )
        return best


def solve(mesh, handles, targets, energy="sarap", X0=None, **kw):
    """One-shot :class:`Solver`: ``Solver(mesh, handles, energy).solve(targets, X0, **kw)``.

    ``start="global"`` selects the multi-start policy of :meth:`Solver.solve_best`.

    Returns
    -------
    result : SolveResult
    """
    return Solver(mesh, handles, energy).solve(targets, X0=X0, **kw)


def _lbfgs_direction(g, S, Y):
    """Two-loop recursion (Nocedal & Wright, Alg. 7.4): −H_k g from the correction pairs."""
    q = -g.copy()
    alphas = []
    for s_, y_ in zip(reversed(S), reversed(Y)):
        a = (s_ @ q) / (y_ @ s_)
        alphas.append(a)
        q -= a * y_
    if S:
        q *= (S[-1] @ Y[-1]) / (Y[-1] @ Y[-1])
    for (s_, y_), a in zip(zip(S, Y), reversed(alphas)):
        q += (a - (y_ @ q) / (y_ @ s_)) * s_
    return q


def solve_lbfgs(mesh, handles, targets, energy="sarap", X0=None, tol=1e-10, max_iter=20000, memory=20):
    """The paper's baseline: L-BFGS on the same energy with the handles eliminated.

    scipy's L-BFGS-B aborts its line search as soon as a trial step flips a triangle (the barrier
    energies are +inf there), so this is the textbook two-loop L-BFGS (Nocedal & Wright, Alg. 7.4)
    with the same :func:`line_search` as :class:`Solver`. It starts from the same map as
    :meth:`Solver.solve` would. It minimises Eq. (11) itself (no smoothing).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    targets : (h,2) numpy array
        One row per handle, in the order of ``handles``.
    energy : str
    X0 : (n,2) numpy array, optional
        A start (flip-free for barrier energies); its handle rows are set to the targets. Default
        :func:`start_for`.
    tol : float
        Stop when an iteration reduces the energy by less than ``tol`` · E.
    max_iter : int
    memory : int
        Number of correction pairs.

    Returns
    -------
    result : SolveResult
        ``converged`` also requires the checks of :meth:`Solver.verify`.
    """
    solver = Solver(mesh, handles, energy)
    tol, max_iter = check_tol(tol), check_max_iter(max_iter)
    T = solver.targets_of(targets)
    X = np.array(start_for(solver, targets) if X0 is None else X0, dtype=float)
    X[solver.handles] = T
    if solver.barrier and count_flips(mesh, X):
        raise ValueError("the L-BFGS start has flipped triangles; the barrier energy needs a flip-free start")
    free = solver.free
    log = _Log(max_iter)

    def fun(X):
        psi, dpsi = en.gradient(mesh.jacobians(X), energy)
        E = float(mesh.areas @ psi)
        g = mesh.jacobian_operator.T @ (mesh.areas[:, None] * dpsi.reshape(-1, 4)).ravel()  # as in Newton
        return E, g[free]

    E, g = fun(X)
    log.record(E)
    S, Y = [], []
    ok, reason = False, f"iteration limit {max_iter} reached"
    while not log.exhausted:
        log.iters += 1
        p = _lbfgs_direction(g, S, Y)
        slope = float(g @ p)
        if slope >= 0:  # not a descent direction: restart from steepest descent
            S, Y = [], []
            p, slope = -g, -float(g @ g)
        found = line_search(
            lambda Z: (solver.energy_of(Z),),
            X,
            solver._full(p),
            E,
            slope,
            mesh if solver.barrier else None,
            min_step=1e-16,
        )
        if found is None:
            ok, reason = True, "line search stalled: no further decrease at round-off"
            break
        step, Xn, _ = found
        En, gn = fun(Xn)
        S.append(step * p)
        Y.append(gn - g)
        if len(S) > memory:
            S.pop(0)
            Y.pop(0)
        decrease = E - En
        X, E, g = Xn, En, gn
        log.record(E)
        if decrease <= tol * E:
            ok, reason = True, f"energy decrease {decrease:.2e} <= tol·E"
            break
    return solver._result(log, X, T, reason, "X0" if X0 is not None else "rest", ok)


def start_for(solver, targets):
    """A start with the handles at ``targets``: flip-free for barrier energies (a continuation
    solve when needed), else the rest pose plus the biharmonic extension.

    Parameters
    ----------
    solver : Solver
    targets : (h,2) numpy array
        One row per handle given to the solver (``solver.handles_given``, in that order).

    Returns
    -------
    X0 : (n,2) numpy array
    """
    mesh = solver.mesh
    T = solver.targets_of(targets)
    X = mesh.V + solver.extend(T - mesh.V[solver.handles])
    X[solver.handles] = T
    if solver.barrier and count_flips(mesh, X):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)
            X = solver.solve(targets, tol=1e-4).X  # a flip-free (approximate) minimiser as the start
    return X


def solve_libigl_arap(mesh, handles, targets, X0=None, iterations=100, history=False):
    """libigl's local–global ARAP (``ARAP_ENERGY_TYPE_ELEMENTS``), the ARAP baseline.

    It minimises Σ_t A_t ‖J_t − R_t‖²_F over maps and rotations, whose minimum over R_t is the
    ARAP energy (10) with signed singular values. libigl has no convergence test; it runs
    exactly ``iterations`` local–global iterations.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    targets : (h,2) numpy array
    X0 : (n,2) numpy array, optional
        Start (default: the rest pose with the handles at the targets).
    iterations : int
    history : bool
        Also record the ARAP energy after every iteration (runs one iteration per call).

    Returns
    -------
    result : SolveResult
        ``converged`` is True when the last iteration changed the energy by less than 1e-10 relative and
        the checks of :meth:`Solver.verify` pass.
    """
    import igl

    solver = Solver(mesh, handles, "arap")
    T = solver.targets_of(targets)
    h = solver.handles
    U = mesh.V.copy() if X0 is None else np.array(X0, dtype=float)
    U[h] = T
    t0 = time.perf_counter()
    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
    data.max_iter = 1 if history else int(iterations)
    V, F = np.ascontiguousarray(mesh.V), np.ascontiguousarray(mesh.F, dtype=np.int64)
    igl.arap_precomputation(V, F, 2, h, data)
    hist_E = [en.total_energy(mesh, U, "arap")]
    hist_t = [0.0]
    U = np.ascontiguousarray(U)
    bc = np.ascontiguousarray(T)
    if history:
        for _ in range(int(iterations)):
            U = np.asarray(igl.arap_solve(bc, data, U))
            hist_E.append(en.total_energy(mesh, U, "arap"))
            hist_t.append(time.perf_counter() - t0)
    else:
        U = np.asarray(igl.arap_solve(bc, data, U))
        hist_E.append(en.total_energy(mesh, U, "arap"))
        hist_t.append(time.perf_counter() - t0)
    E = hist_E[-1]
    conv = len(hist_E) > 2 and abs(hist_E[-2] - E) <= 1e-10 * max(E, 1e-300)
    check = solver.verify(np.asarray(U), T)
    reason = f"{iterations} local-global iterations" + ("" if check.ok else f"; check failed: {check.reason}")
    return SolveResult(
        np.array(U),
        E,
        np.array(hist_E),
        np.array(hist_t),
        int(iterations),
        time.perf_counter() - t0,
        bool(conv and check.ok),
        reason,
        count_flips(mesh, U),
    )
