"""The variational DefOp D^E: minimise a deformation energy subject to point-handle constraints.

Problem (6) of the paper: min_X E(X) = Σ_t A_t ψ(J_t(X)) subject to X[handles] = targets, over
piecewise-linear maps X (n,2). :class:`Solver` precomputes everything that depends only on the
mesh, the handle set and the energy, then solves by projected Newton:

* handles are hard constraints, eliminated from the system (only free vertices are unknowns);
* the Hessian Σ_t A_t B_tᵀ H_t B_t (H_t the PSD-projected Hessian of :mod:`defop.energies`) is
  assembled into a fixed sparsity pattern, so only its values change between iterations;
* it is factorised with QDLDL (an LDLᵀ whose AMD ordering and symbolic analysis are computed
  once per Solver and reused by ``update`` in every iteration and every solve: 2 ms instead of
  10–17 ms for SuperLU on the aleph; scipy's ``splu`` is the fallback when qdldl is missing);
* once the decrement is small (λ²/2 ≤ 1e-2·E) the exact Hessian replaces the projected one while
  it gives a descent direction: the clamped eigenvalues make projected Newton converge only
  linearly near the optimum (aleph, warm S-ARAP solve: 28 → 6 iterations);
* Armijo backtracking; for the barrier energies (S-ARAP, isometric) the step is first capped by
  the flip-free maximum step of Smith & Schaefer (2015), so no triangle ever flips;
* stopping rule: the Newton decrement λ² = −gᵀp relative to the energy, λ²/2 ≤ tol·E.

Starts: any flip-free map can warm-start a solve (``X0``); its handles need not be at the
targets. From the start, the handles are moved to their targets through a biharmonic
extension of their displacement; for the barrier energies, if that would flip a triangle, the
handles are moved progressively (continuation), re-solving at each intermediate stage, halving
the stage length when a stage would flip. Every start handed to Newton is flip-free.

Baselines on the same energies: :func:`solve_lbfgs` (scipy's L-BFGS, the paper's method) and,
for ARAP, :func:`solve_libigl_arap` (libigl's local–global ARAP, ``ARAP_ENERGY_TYPE_ELEMENTS``).
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from . import energies as en

try:  # QDLDL reuses the symbolic factorisation (AMD ordering, elimination tree) across updates
    import qdldl
except ImportError:  # pragma: no cover - exercised only without the dependency
    qdldl = None


class NotConvergedWarning(RuntimeWarning):
    """A solve stopped at its iteration limit before meeting its tolerance."""


@dataclasses.dataclass
class SolveResult:
    """Outcome of a solve.

    Attributes
    ----------
    X : (n,2) numpy array
        Deformed positions; ``X[handles] == targets``.
    energy : float
        Final E(X).
    energy_history : (k,) numpy array
        E after each iteration (the start first).
    time_history : (k,) numpy array
        Seconds since the start of the solve at each entry of ``energy_history``.
    iterations : int
        Newton (or L-BFGS / local-global) iterations, continuation stages included.
    time : float
        Wall-clock seconds.
    converged : bool
    reason : str
        Why it stopped.
    flips : int
        Flipped triangles in ``X``.
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


def count_flips(mesh, X):
    """Number of triangles with det J ≤ 0 (flipped or collapsed).

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    X : (n,2) numpy array

    Returns
    -------
    n : int
    """
    return int(np.count_nonzero(mesh.flipped(X)))


def _check_handles(mesh, handles):
    h = np.asarray(handles)
    if h.ndim != 1 or len(h) == 0:
        raise ValueError(f"handles must be a non-empty 1-d array of vertex indices, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.integer):
        if not np.all(np.equal(np.mod(h, 1), 0)):
            raise ValueError("handles must be integer vertex indices")
        h = h.astype(np.int64)
    bad = np.flatnonzero((h < 0) | (h >= mesh.n_vertices))
    if len(bad):
        raise ValueError(
            f"handle {int(bad[0])} is vertex index {int(h[bad[0]])}, "
            f"out of range for a mesh of {mesh.n_vertices} vertices"
        )
    return h.astype(np.int64)


def _check_targets(targets, handles):
    T = np.asarray(targets, dtype=float)
    if T.shape != (len(handles), 2):
        raise ValueError(f"targets must have shape ({len(handles)}, 2), one row per handle, got {T.shape}")
    if not np.isfinite(T).all():
        k = int(np.argwhere(~np.isfinite(T))[0, 0])
        raise ValueError(f"target {k} of handle vertex {int(handles[k])} is not finite: {T[k]}")
    return T


def _unique_handles(handles, targets):
    """Merge handles given twice with the same target; raise if a vertex gets two targets."""
    uniq, first, inv = np.unique(handles, return_index=True, return_inverse=True)
    if len(uniq) == len(handles):
        return handles, targets
    for k in range(len(handles)):
        j = first[inv[k]]
        if not np.allclose(targets[k], targets[j], rtol=0, atol=1e-12):
            raise ValueError(
                f"vertex {int(handles[k])} is given two different targets: {tuple(targets[j])} and {tuple(targets[k])}"
            )
    return handles[first], targets[first]


class _Factor:
    """Sparse SPD solve with the symbolic analysis done once (QDLDL) or, without qdldl, SuperLU."""

    def __init__(self):
        self._solver = None

    def solve(self, A, b):
        if qdldl is not None:
            if self._solver is None:
                self._solver = qdldl.Solver(A, upper=True)
            else:
                self._solver.update(A, upper=True)
            return self._solver.solve(b)
        return sla.splu(A, permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True)).solve(b)


class Solver:
    """Projected-Newton solver of problem (6) on one mesh, one handle set and one energy.

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices of all constrained vertices (moving and fixed handles). A vertex listed
        twice must get the same target each time.
    energy : str
        ``"arap"`` (Eq. 10), ``"sarap"`` (Eq. 11) or ``"isometric"``.
    tol : float
        Default stopping tolerance: the Newton decrement λ²/2 ≤ tol · E.
    max_iter : int
        Default iteration limit (continuation stages included).
    smoothing : tuple of float, optional
        S-ARAP only: the μ of the smoothed kink (:func:`defop.energies._psi_sarap_smooth`), one Newton
        stage per entry, the last to ``tol``. The default ``(1e-5,)`` moves the minimiser by at most
        1.3e-5 of the bounding-box diagonal from the μ → 1e-9 limit (aleph, measured), two orders below
        the error of any fitted operator; ``(1e-5, 1e-7, 1e-9)`` reaches Eq. (11)'s own minimum to
        a relative energy gap below 1e-8, at about twice the iterations.

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
        self.handles_given = _check_handles(mesh, handles)
        self.handles = np.unique(self.handles_given)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        n = mesh.n_vertices
        is_handle = np.zeros(n, bool)
        is_handle[self.handles] = True
        self.free_vertices = np.flatnonzero(~is_handle)
        self.free = np.column_stack([2 * self.free_vertices, 2 * self.free_vertices + 1]).ravel()
        self._precompute_pattern()
        self._factor = _Factor()
        self._biharmonic = None
        #: S-ARAP's kink on conformal Jacobians is smoothed by μ (energies._psi_sarap_smooth)
        if self.energy != "sarap":
            self.mu_schedule = (0.0,)
        else:
            self.mu_schedule = (1e-5,) if smoothing is None else tuple(float(m) for m in smoothing)
            if not self.mu_schedule or min(self.mu_schedule) < 0:
                raise ValueError(f"smoothing must be a non-empty sequence of μ >= 0, got {smoothing!r}")
        #: switch from the projected to the exact Hessian once λ²/2 ≤ exact_switch · E
        self.exact_switch = 1e-2
        #: tolerance of the intermediate μ stages of a smoothing schedule. Converging each stage tightly
        #: matters: from a loosely converged stage, Newton on the next, sharper kink (curvature ~ 1/μ)
        #: crawls with tiny steps — measured on 4 problems per shape with (1e-5, 1e-7, 1e-9), a stage
        #: tolerance of 1e-4 took up to 0.80 s (gingerbread) and 0.28 s (aleph) to a gap of 1e-8, 1e-8
        #: took at most 0.08 s
        self.stage_tol = 1e-8

    # ------------------------------------------------------------------ precomputation
    def _precompute_pattern(self):
        mesh = self.mesh
        F = mesh.F
        m = len(F)
        dofs = np.stack([2 * F, 2 * F + 1], axis=-1).reshape(m, 6)  # local dof 2i+c -> global
        rows = np.repeat(dofs, 6, axis=1).ravel()
        cols = np.tile(dofs, (1, 6)).ravel()
        ndof = 2 * mesh.n_vertices
        gmap = -np.ones(ndof, np.int64)
        gmap[self.free] = np.arange(len(self.free))
        r, c = gmap[rows], gmap[cols]
        keep = (r >= 0) & (c >= 0) & (r <= c)  # upper triangle of the free-free block (QDLDL input)
        self._keep = np.flatnonzero(keep)
        nf = len(self.free)
        key = c[keep] * nf + r[keep]  # column-major order = CSC
        uniq, inv = np.unique(key, return_inverse=True)
        self._inv = inv
        self._csc_rows = (uniq % nf).astype(np.int32)
        colcount = np.bincount(uniq // nf, minlength=nf)
        self._csc_ptr = np.concatenate([[0], np.cumsum(colcount)]).astype(np.int32)
        self._nnz = len(uniq)
        self._nf = nf
        diag = uniq[(uniq % nf) == (uniq // nf)]
        self._diag_pos = np.searchsorted(uniq, diag)

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_factor"] = None
        state["_biharmonic"] = None
        state.pop("_K", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._factor = _Factor()

    # ------------------------------------------------------------------ energy pieces
    def energy_of(self, X, mu=0.0):
        """E(X) (+inf for a flipped triangle under a barrier energy); ``mu`` smooths S-ARAP's kink."""
        return en.total_energy(self.mesh, X, self.energy, mu)

    def _energies(self, X, mu):
        """(E_μ(X), E(X)): the smoothed energy Newton minimises and the true one, from one SVD."""
        if not mu:
            E = self.energy_of(X)
            return E, E
        S = en._svd_frame(self.mesh.jacobians(X))[0]
        A = self.mesh.areas
        smooth, exact = en._psi_value(self.energy, S[:, 0], S[:, 1], mu, both=True)
        return float(A @ smooth), float(A @ exact)

    def _grad_hess(self, X, mu=0.0, project=True):
        """E, the gradient (2n,) and the Hessian values in the fixed upper-triangular CSC pattern.

        Per triangle, K_t = A_t Σ_k λ_k w_k w_kᵀ with w_k = B_tᵀ vec(M_k) for the eigenpairs (λ_k, M_k)
        of :func:`defop.energies.eigensystem`: no 4×4 Hessian is formed. Also returns ``local``, with
        which :meth:`_assemble` rebuilds the projected Hessian without a second eigensystem.
        """
        mesh = self.mesh
        G = mesh.jacobian_operator
        J = (G @ np.asarray(X, dtype=float).ravel()).reshape(-1, 2, 2)
        psi, grad, lam, modes = en.eigensystem(J, self.energy, project=False, mu=mu)
        A = mesh.areas
        E = float(A @ psi)
        g = G.T @ (A[:, None] * grad).ravel()
        D = mesh.local_gradients  # (m,3,2)
        m = len(D)
        # w_k[2i+a] = Σ_b ∇φ_i[b] M_k[a,b]: one (3,2)@(2,8) product per triangle
        Mb = np.ascontiguousarray(modes.reshape(m, 2, 2, 4).transpose(0, 2, 1, 3)).reshape(m, 2, 8)
        local = (np.matmul(D, Mb).reshape(m, 6, 4), lam * A[:, None])
        return E, g, self._assemble(local, project), local

    def _assemble(self, local, project=True):
        """Hessian values in the CSC pattern from per-triangle modes W (m,6,4) and A_t·λ (m,4); ``project``
        clamps the element eigenvalues at 0 (the PSD projection)."""
        W, lamA = local
        if project:
            lamA = np.maximum(lamA, 0.0)
        K_loc = np.matmul(W * lamA[:, None, :], np.swapaxes(W, 1, 2))  # (m,6,6)
        return np.bincount(self._inv, weights=K_loc.reshape(-1)[self._keep], minlength=self._nnz)

    def _newton_direction(self, g_free, data):
        # a tiny relative diagonal shift keeps the projected (PSD) Hessian definite; the exact Hessian
        # may be indefinite: the caller checks that the direction descends
        shift = 1e-10 * max(float(np.mean(np.abs(data[self._diag_pos]))), 1e-300)
        K = getattr(self, "_K", None)
        if K is None:  # the pattern is fixed: build the CSC matrix once, then only overwrite its values
            K = self._K = sp.csc_matrix((data.copy(), self._csc_rows, self._csc_ptr), shape=(self._nf, self._nf))
        K.data[:] = data
        K.data[self._diag_pos] += shift
        if qdldl is None:
            K = K + sp.triu(K, 1).T
        return -self._factor.solve(K, g_free)

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
        displacement : (h,2) numpy array
            Displacement of each (unique) handle vertex, in the order of ``self.handles``.

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

    # ------------------------------------------------------------------ solve
    def solve(self, targets, X0=None, tol=None, max_iter=None, max_stages=64):
        """Minimise the energy with the handles at ``targets``.

        Parameters
        ----------
        targets : (h,2) numpy array
            Target positions, one row per entry of ``handles`` given to the constructor.
        X0 : (n,2) numpy array, optional
            Warm start (any map; flip-free for a barrier energy). Its handle rows need not be at
            the targets. Default: the rest pose.
        tol : float, optional
            Newton-decrement tolerance relative to the energy (default ``self.tol``).
        max_iter : int, optional
            Iteration limit (default ``self.max_iter``).
        max_stages : int
            Limit on continuation stages for far moves.

        Returns
        -------
        result : SolveResult
            ``converged`` is False (and a :class:`NotConvergedWarning` is issued) when the
            iteration limit was hit.

        Raises
        ------
        ValueError
            Targets of the wrong shape or not finite, a vertex with two different targets,
            or a flipped start for a barrier energy.
        """
        t0 = time.perf_counter()
        tol = self.tol if tol is None else float(tol)
        max_iter = self.max_iter if max_iter is None else int(max_iter)
        T = _check_targets(targets, self.handles_given)
        _, T = _unique_handles(self.handles_given, T)
        mesh = self.mesh
        if X0 is None:
            X = mesh.V.copy()
        else:
            X = np.array(X0, dtype=float)
            if X.shape != mesh.V.shape:
                raise ValueError(f"X0 must have shape {mesh.V.shape}, got {X.shape}")
            if not np.isfinite(X).all():
                raise ValueError("X0 has NaN or infinite entries")
            if self.barrier:
                nf = count_flips(mesh, X)
                if nf:
                    raise ValueError(
                        f"X0 has {nf} flipped triangle(s) (first: triangle {int(np.flatnonzero(mesh.flipped(X))[0])}); "
                        f"the {self.energy} energy is a barrier and needs a flip-free start"
                    )
        hist_E, hist_t = [], []
        state = {"iters": 0}
        budget = max_iter

        def newton(X, tol, limit):
            """Newton at fixed handles; S-ARAP runs through its smoothing schedule. Returns (X, converged, reason)."""
            for i, mu in enumerate(self.mu_schedule):
                last = i == len(self.mu_schedule) - 1
                X, converged, reason = newton_mu(X, tol if last else max(tol, self.stage_tol), limit, mu)
                if not converged and state["iters"] >= budget:
                    break  # an intermediate stage only has to be a good start for the next μ
            return X, converged, reason

        def newton_mu(X, tol, limit, mu):
            E, E_true = self._energies(X, mu)
            hist_E.append(E_true)
            hist_t.append(time.perf_counter() - t0)
            stalls = 0
            rel_dec = np.inf
            exact_ok = True
            for _ in range(limit):
                if state["iters"] >= budget:
                    return X, False, f"iteration limit {budget} reached"
                exact = exact_ok and rel_dec <= self.exact_switch
                # near the optimum: the exact Hessian gives quadratic convergence where the projected
                # one (clamped element eigenvalues) converges only linearly; use it while it descends
                E, g, data, local = self._grad_hess(X, mu, project=not exact)
                gf = g[self.free]
                p = self._newton_direction(gf, data)
                dec = -float(gf @ p)  # Newton decrement λ²
                if exact and not (np.isfinite(dec) and dec > 0):
                    exact = False  # indefinite: fall back to the projected Hessian, same eigensystem
                    p = self._newton_direction(gf, self._assemble(local))
                    dec = -float(gf @ p)
                if not np.isfinite(dec):
                    return X, False, "Newton direction is not finite (degenerate Hessian)"
                rel_dec = dec / 2 / max(E, 1e-300)
                if dec / 2 <= tol * max(E, 1e-300) or E == 0.0:
                    return X, True, f"Newton decrement λ²/2 = {dec / 2:.2e} <= tol·E"
                state["iters"] += 1
                P = np.zeros(2 * mesh.n_vertices)
                P[self.free] = p
                P = P.reshape(-1, 2)
                step = 1.0
                if self.barrier:
                    step = en.max_flip_free_step(mesh.jacobians(X), mesh.jacobians(P))
                slope = -dec
                while True:
                    Xn = X + step * P
                    En, En_true = self._energies(Xn, mu)
                    if En <= E + 1e-4 * step * slope:
                        break
                    step *= 0.5
                    if exact and step < 1e-3:  # the exact Hessian's model is poor here: back to the projected one
                        exact_ok = False
                        break
                    if step < 1e-12:
                        hist_E.append(self.energy_of(X))
                        hist_t.append(time.perf_counter() - t0)
                        converged = dec / 2 <= 1e-6 * max(E, 1e-300)  # at round-off: as good as it gets
                        why = "line search stalled at round-off" if converged else "line search failed"
                        return X, converged, why
                if exact and not exact_ok:
                    state["iters"] -= 1
                    continue
                X = Xn
                hist_E.append(En_true)
                hist_t.append(time.perf_counter() - t0)
                if exact and step == 1.0 and dec / 2 <= 10 * tol * max(E, 1e-300):
                    # a full exact Newton step from λ²/2 ≤ 10·tol·E lands within O(λ⁴) of the optimum
                    # (quadratic convergence): the next decrement would pass; skip computing it
                    return X, True, f"full Newton step from λ²/2 = {dec / 2:.2e} <= 10·tol·E"
                # S-ARAP triangles sitting on the (smoothed) kink make the last digits converge linearly:
                # three steps in a row that each gain less than tol·E mean the energy has converged
                stalls = stalls + 1 if E - En <= tol * E else 0
                if stalls >= 3:
                    return X, True, f"energy stagnated: 3 steps each reduced E by <= {tol:g}·E"
            return X, False, f"iteration limit {limit} reached"

        # move the handles from where X has them to the targets (continuation for barrier energies)
        start_h = X[self.handles].copy()
        s = 0.0
        frac = 1.0
        stages = 0
        converged, reason = True, ""
        while s < 1.0:
            stages += 1
            if stages > max_stages:
                converged, reason = False, f"continuation needed more than {max_stages} stages"
                break
            s_next = min(1.0, s + frac)
            D = self.extend((s_next - s) * (T - start_h))
            Xt = X + D
            if self.barrier and np.any(mesh.flipped(Xt)):
                frac /= 2
                if frac < 1e-6:
                    converged, reason = False, "could not move the handles without flipping a triangle"
                    break
                stages -= 1
                continue
            Xt[self.handles] = start_h + s_next * (T - start_h)
            s = s_next
            stage_tol = tol if s >= 1.0 else max(tol, 1e-4)
            X, converged, reason = newton(Xt, stage_tol, budget - state["iters"])
            if not converged and s < 1.0 and state["iters"] < budget:
                converged = True  # an intermediate stage only needs to be a good start
            if state["iters"] >= budget and not converged:
                break
            frac = min(1.0 - s, 2 * frac) if s < 1.0 else frac
        if s < 1.0 and converged:
            converged, reason = False, "iteration limit reached during continuation"
        if converged and stages > 1:
            reason += f" (after {stages} continuation stages)"
        E = self.energy_of(X)
        result = SolveResult(
            X=X,
            energy=E,
            energy_history=np.array(hist_E),
            time_history=np.array(hist_t),
            iterations=state["iters"],
            time=time.perf_counter() - t0,
            converged=bool(converged and s >= 1.0),
            reason=reason,
            flips=count_flips(mesh, X),
        )
        if not result.converged:
            warnings.warn(f"{self.energy} solve did not converge: {reason}", NotConvergedWarning, stacklevel=2)
        return result


def solve(mesh, handles, targets, energy="sarap", X0=None, **kw):
    """One-shot :class:`Solver` (``Solver(mesh, handles, energy).solve(targets, X0, **kw)``).

    Returns
    -------
    result : SolveResult
    """
    return Solver(mesh, handles, energy).solve(targets, X0=X0, **kw)


def solve_lbfgs(mesh, handles, targets, energy="sarap", X0=None, tol=1e-10, max_iter=20000, memory=20):
    """The paper's baseline: L-BFGS on the same energy with the handles eliminated.

    scipy's L-BFGS-B aborts its line search as soon as a trial step flips a triangle (the barrier
    energies are +inf there), so this is the textbook two-loop L-BFGS (Nocedal & Wright, Alg. 7.4)
    with the same line search as :class:`Solver`: the flip-free maximum step for barrier energies,
    then Armijo backtracking. It starts from the same map as :meth:`Solver.solve` would.

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    handles : (h,) int numpy array
    targets : (h,2) numpy array
    energy : str
    X0 : (n,2) numpy array, optional
        A start (flip-free for barrier energies) with the handles at the targets; default
        :func:`start_for`.
    tol : float
        Stop when an iteration reduces the energy by less than ``tol`` · E.
    max_iter : int
    memory : int
        Number of correction pairs.

    Returns
    -------
    result : SolveResult
    """
    solver = Solver(mesh, handles, energy)
    T = _check_targets(targets, solver.handles_given)
    _, T = _unique_handles(solver.handles_given, T)
    if X0 is None:
        X0 = start_for(solver, T)
    X = np.array(X0, dtype=float)
    X[solver.handles] = T
    if solver.barrier and count_flips(mesh, X):
        raise ValueError("the L-BFGS start has flipped triangles; the barrier energy needs a flip-free start")
    free = solver.free
    t0 = time.perf_counter()

    def fun(X):
        psi, dpsi = en.gradient(mesh.jacobians(X), energy)
        E = float(mesh.areas @ psi)
        g = mesh.jacobian_operator.T @ (mesh.areas[:, None] * dpsi.reshape(-1, 4)).ravel()  # as in Newton
        return E, g[free]

    E, g = fun(X)
    hist_E, hist_t = [E], [0.0]
    S, Y = [], []
    converged, reason = False, f"iteration limit {max_iter} reached"
    it = 0
    while it < max_iter:
        it += 1
        q = -g.copy()
        alphas = []
        for s_, y_ in zip(reversed(S), reversed(Y)):
            a = (s_ @ q) / (y_ @ s_)
            alphas.append(a)
            q -= a * y_
        if S:
            q *= (S[-1] @ Y[-1]) / (Y[-1] @ Y[-1])
        for (s_, y_), a in zip(zip(S, Y), reversed(alphas)):
            b = (y_ @ q) / (y_ @ s_)
            q += (a - b) * s_
        p = q
        slope = float(g @ p)
        if slope >= 0:  # not a descent direction: restart from steepest descent
            S, Y = [], []
            p, slope = -g, -float(g @ g)
        P = np.zeros(2 * mesh.n_vertices)
        P[free] = p
        P = P.reshape(-1, 2)
        step = 1.0
        if solver.barrier:
            step = en.max_flip_free_step(mesh.jacobians(X), mesh.jacobians(P))
        while True:
            Xn = X + step * P
            En = solver.energy_of(Xn)
            if En <= E + 1e-4 * step * slope:
                break
            step *= 0.5
            if step < 1e-16:
                break
        if step < 1e-16:
            converged, reason = True, "line search stalled: no further decrease at round-off"
            break
        En, gn = fun(Xn)
        S.append(step * p)
        Y.append(gn - g)
        if len(S) > memory:
            S.pop(0)
            Y.pop(0)
        decrease = E - En
        X, E, g = Xn, En, gn
        hist_E.append(E)
        hist_t.append(time.perf_counter() - t0)
        if decrease <= tol * E:
            converged, reason = True, f"energy decrease {decrease:.2e} <= tol·E"
            break
    return SolveResult(
        X, E, np.array(hist_E), np.array(hist_t), it, time.perf_counter() - t0, converged, reason, count_flips(mesh, X)
    )


def start_for(solver, targets):
    """A start with the handles at ``targets``: flip-free for barrier energies (a continuation
    solve when needed), else the rest pose plus the biharmonic extension.

    Parameters
    ----------
    solver : Solver
    targets : (h,2) numpy array
        One row per unique handle (``solver.handles``).

    Returns
    -------
    X0 : (n,2) numpy array
    """
    mesh = solver.mesh
    X = mesh.V + solver.extend(targets - mesh.V[solver.handles])
    X[solver.handles] = targets
    if solver.barrier and count_flips(mesh, X):
        X = solver.solve(targets, tol=1e-4).X  # a flip-free (approximate) minimiser as the start
    return X


def solve_libigl_arap(mesh, handles, targets, X0=None, iterations=100, history=False):
    """libigl's local–global ARAP (``ARAP_ENERGY_TYPE_ELEMENTS``), the ARAP baseline.

    It minimises Σ_t A_t ‖J_t − R_t‖²_F over maps and rotations, whose minimum over R_t is the
    ARAP energy (10) with signed singular values. libigl has no convergence test; it runs
    exactly ``iterations`` local–global iterations.

    Parameters
    ----------
    mesh : defop.mesh.Mesh
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
        ``converged`` is True when the last iteration changed the energy by less than 1e-10 relative.
    """
    import igl

    h = _check_handles(mesh, handles)
    T = _check_targets(targets, h)
    h, T = _unique_handles(h, T)
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
    return SolveResult(
        np.array(U),
        E,
        np.array(hist_E),
        np.array(hist_t),
        int(iterations),
        time.perf_counter() - t0,
        bool(conv),
        f"{iterations} local-global iterations",
        count_flips(mesh, U),
    )
