"""Other solvers of problem (6) on the same energies as :class:`defop.variational.solver.Solver`, verified by the
same checks: the baselines the Newton solver is compared with.

:func:`solve_lbfgs`: the paper's method, L-BFGS (with the Newton solver's line search); :func:`solve_libigl_arap`:
libigl's local–global ARAP (``ARAP_ENERGY_TYPE_ELEMENTS``); :func:`start_for`: the start both are given.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..variational import energies as en
from ..variational.newton import Log, line_search
from ..variational.problem import check_max_iter, check_tol, count_flips
from ..variational.solver import NotConvergedWarning, Solver, SolveResult

__all__ = ["solve_lbfgs", "solve_libigl_arap", "start_for"]


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
    targets : (h, d) numpy array
        One row per handle, in the order of ``handles``.
    energy : str
    X0 : (n, d) numpy array, optional
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
    log = Log(max_iter)

    def fun(X):
        psi, dpsi = en.gradient(mesh.jacobians(X), energy)
        E = float(mesh.areas @ psi)
        g = mesh.jacobian_operator.T @ (mesh.areas[:, None] * dpsi.reshape(len(psi), -1)).ravel()  # as in Newton
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
            solver.full(p),
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
    return solver.finish(log, X, T, reason, "X0" if X0 is not None else "rest", ok)


def start_for(solver, targets):
    """A start with the handles at ``targets``: flip-free for barrier energies (a continuation
    solve when needed), else the rest pose plus the biharmonic extension.

    Parameters
    ----------
    solver : Solver
    targets : (h, d) numpy array
        One row per handle given to the solver (``solver.handles_given``, in that order).

    Returns
    -------
    X0 : (n, d) numpy array
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
    targets : (h, d) numpy array
    X0 : (n, d) numpy array, optional
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
    igl.arap_precomputation(V, F, mesh.V.shape[1], h, data)
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
