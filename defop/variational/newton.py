"""Projected Newton on problem (6): stages, S-ARAP's smoothing schedule, the line search, continuation.

* Newton starts with the PSD-projected Hessian (:func:`defop.variational.energies.eigensystem`, clamped) and,
  once the decrement is small (λ²/2 ≤ ``exact_switch``·E), uses the exact one while it gives a descent
  direction: the clamped eigenvalues make projected Newton converge only linearly near the optimum (aleph,
  warm S-ARAP solve: 28 → 6 iterations).
* One line search (:func:`line_search`, shared with :func:`defop.variational.baselines.solve_lbfgs`): for the
  barrier energies (S-ARAP, isometric) the step is first capped by the flip-free maximum step of Smith &
  Schaefer (2015), so no element ever flips, then Armijo backtracking.
* S-ARAP's kink (Eq. 11 is not differentiable on conformal Jacobians) is smoothed by μ for the first Newton
  stages; the last stage always minimises Eq. (11) itself (μ = 0), holding triangles on the kink
  (:func:`kink_active_set`).
* From a start whose handles are not at the targets, the handles move there through a biharmonic extension of
  their displacement; for the barrier energies, if that would flip an element, progressively (continuation,
  :func:`continuation`), halving the stage length when a stage would flip.

Every function takes the :class:`defop.variational.solver.Solver` (the reduced problem and its settings) first.
"""

from __future__ import annotations

import time

import numpy as np

from . import energies as en
from . import kink
from .backend import forcing
from .inertia import inertia_shift

#: at most this many triangles are released from the kink in one Newton solve (:func:`kink_active_set`)
MAX_RELEASES = 64
#: S-ARAP: the smoothing continues (μ / 100, :func:`defop.variational.kink.refine`) while the held point's Fenchel gap
#: (:func:`defop.variational.kink.fenchel_gap`) exceeds this fraction of ``verify_tol`` · E
KINK_TARGET = 0.1
#: ``"isometric_exp"`` only: a continuation stage whose start raises the largest log(1 + ψ) over the triangles by
#: more than this is halved like one that flips. Newton on ψ = exp(s·x) − 1 lowers the exponent by about one per
#: iteration, so a start at ψ ~ 1e259 (a full stage after a converged half stage, bar of 43 vertices) spent the whole
#: 300-iteration budget; a bound on the growth, not on ψ itself, still lets a huge stretch (ψ ~ 1e10 at the minimum)
#: converge
MAX_STAGE_GROWTH = {"isometric_exp": 20.0}


class Log:
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


def line_search(fun, X, P, E, slope, mesh=None, min_step=1e-12, c=1e-4):
    """Armijo backtracking along P, first capped by the flip-free maximum step when ``mesh`` is given.

    The one line search of Newton and :func:`defop.variational.baselines.solve_lbfgs`.

    Parameters
    ----------
    fun : callable
        ``fun(X) -> tuple`` whose first entry is the energy to decrease (further entries are passed back).
    X, P : (n, d) numpy arrays
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


def step_off(solver, X, D):
    """A flip-free point along D from X (a saddle, or a point on S-ARAP's kink) with lower energy, or None."""
    E = solver.energy_of(X)
    step = 0.05 * solver.mesh.bbox_diagonal / max(float(np.abs(D).max()), 1e-300)
    if solver.barrier:
        step *= en.max_flip_free_step(solver.mesh.jacobians(X), solver.mesh.jacobians(step * D))
    for _ in range(40):
        Xs = X + step * D
        if solver.energy_of(Xs) < E - 1e-12 * abs(E):
            return Xs
        step *= 0.5
    return None


def continuation(solver, log, X, T, tol, max_stages):
    """Move the handles from X's to T (barrier energies: in flip-free stages), Newton at each stage.

    Returns (X, reached, reason, ok): ``reached`` is False when the handles could not be moved all the way,
    ``ok`` whether the last Newton stage met its tolerance.
    """
    mesh = solver.mesh
    start_h = X[solver.handles].copy()
    s, frac, stages = 0.0, 1.0, 0
    reason = ""
    while s < 1.0:
        if stages >= max_stages:
            return X, False, f"continuation needed more than {max_stages} stages", False
        s_next = min(1.0, s + frac)
        Xt = X + solver.extend((s_next - s) * (T - start_h))
        if (solver.barrier and np.any(mesh.flipped(Xt))) or too_steep(solver, X, Xt):
            frac /= 2
            if frac < 1e-6:
                return X, False, "could not move the handles without flipping a triangle", False
            continue
        stages += 1
        Xt[solver.handles] = start_h + s_next * (T - start_h)
        if solver.barrier and s_next >= 1.0 and np.any(mesh.flipped(Xt)):
            return X, False, "the targets collapse or flip a triangle between handles", False
        s = s_next
        X, converged, reason = newton(solver, log, Xt, tol if s >= 1.0 else max(tol, 1e-4))
        if log.exhausted and not converged:
            return X, s >= 1.0, reason, False
        frac = min(1.0 - s, 2 * frac) if s < 1.0 else frac
    if stages > 1:
        reason += f" (after {stages} continuation stages)"
    return X, True, reason, converged


def too_steep(solver, X, Xt):
    """Whether a stage from X to Xt raises the largest log(1 + ψ) by more than :data:`MAX_STAGE_GROWTH`."""
    grow = MAX_STAGE_GROWTH.get(solver.energy)
    if grow is None:
        return False
    top = [np.log1p(en.density(solver.mesh.jacobians(Y), solver.energy).max()) for Y in (X, Xt)]
    return not top[1] - top[0] <= grow


def newton(solver, log, X, tol):
    """Newton at fixed handles; S-ARAP runs through its smoothing schedule, ending on Eq. (11) itself.

    A schedule of the held μ = 0 stage alone (3D's default) with a ``fallback_schedule`` gets
    ``held_first_iterations`` Newton iterations; where it has not converged by then (every element on a kink, say),
    the fallback schedule runs from the same X."""
    fallback = getattr(solver, "fallback_schedule", None)
    if not fallback or tuple(solver.mu_schedule) != (0.0,):
        return _schedule(solver, log, X, tol, solver.mu_schedule)
    budget = log.budget
    log.budget = min(budget, log.iters + solver.held_first_iterations)
    try:
        Y, converged, reason = _schedule(solver, log, X, tol, solver.mu_schedule)
    finally:
        log.budget = budget
    if converged or log.exhausted:
        return Y, converged, reason
    return _schedule(solver, log, X, tol, fallback)


def _schedule(solver, log, X, tol, schedule):
    """:func:`newton` through the given μ schedule."""
    for i, mu in enumerate(schedule):
        last = i == len(schedule) - 1
        if last and solver.energy == "sarap":
            return kink.refine(
                lambda Y, m: newton_stage(solver, log, Y, max(tol, solver.stage_tol), m),
                lambda Y: kink_active_set(solver, log, Y, tol),
                lambda Y: kink.kink_gap(solver, Y, KINK_TARGET * solver.verify_tol),
                X,
                schedule[i - 1] if i else 0.0,
                KINK_TARGET * solver.verify_tol,
                kink.certificate_mu(solver.energy_of(X), solver.mesh.areas.sum(), solver.verify_tol),
            )
        X, converged, reason = newton_stage(solver, log, X, tol if last else max(tol, solver.stage_tol), mu)
        if log.exhausted:
            break
    return X, converged, reason


def kink_active_set(solver, log, X, tol):
    """Newton on Eq. (11) (μ = 0) with an active set of triangles held on its kink.

    Elements on the kink (the closed forms' ``on_kink``: :func:`defop.variational.planar.on_kink`, in 3D either of
    :func:`defop.variational.volumetric.on_kink`'s two sets) are held there; once Newton has converged, a
    held element that the mesh pulls off harder than its cone bears (:func:`~defop.variational.kink.kink_pull`, from
    the Newton direction of :func:`~defop.variational.inertia.inertia_shift`'s shift)
    is released (from both sets): the solve steps along the pull (a line search on the true energy) and Newton
    continues without holding it. Returns (X, converged, reason) like :func:`newton_stage`.
    """
    hold = np.full(len(solver.mesh.F), solver.kink_threshold)
    released = 0
    while True:
        X, converged, reason = newton_stage(solver, log, X, tol, 0.0, hold)
        if not converged or log.exhausted or released >= MAX_RELEASES:
            return X, converged, reason
        E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=hold)
        p = solver.newton_direction(g[solver.free], data, rel_shift=inertia_shift(solver, data))
        gain, _, D, pulled, _ = kink.kink_pull(solver, X, local, p, hold)
        Xs = None if gain <= tol * solver.scale(E) else step_off(solver, X, D)
        if Xs is None:
            return X, converged, reason + (f" ({released} triangle(s) released from the kink)" if released else "")
        hold[pulled] = -1.0  # never on the kink again in this solve
        released += len(pulled)
        X = Xs


def newton_stage(solver, log, X, tol, mu, hold=None):
    """Projected (then exact) Newton on E_μ from a flip-free X. Returns (X, converged, reason).

    ``hold``: S-ARAP at μ = 0, the per-triangle kink thresholds (default ``KINK``; see
    :func:`defop.variational.planar.on_kink`)."""
    hold = solver.kink_threshold if hold is None else hold
    E, E_true = solver.energies(X, mu)
    log.record(E_true)
    stalls, rel_dec, exact_ok = 0, np.inf, True
    fun = (lambda Y: solver.energies(Y, mu)) if mu else (lambda Y: (solver.energy_of(Y), None))
    while True:
        if log.exhausted:
            return X, False, f"iteration limit {log.budget} reached"
        exact = exact_ok and rel_dec <= solver.exact_switch
        # near the optimum the exact Hessian converges quadratically where the projected one (clamped
        # element eigenvalues) converges only linearly; use it while it descends
        E, g, data, local = solver.grad_hess(X, mu, project=not exact, kink=0.0 if mu else hold)
        gf = g[solver.free]
        # exact steps (near the optimum, the Hessian changing little) may re-use the last exact step's factorisation
        p = solver.newton_direction(gf, data, reuse=forcing(rel_dec) if exact else 0.0)
        dec = -float(gf @ p)  # Newton decrement λ²
        if exact and not (np.isfinite(dec) and dec > 0):
            exact = False  # indefinite: fall back to the projected Hessian, same eigensystem
            p = solver.newton_direction(gf, solver.hessian.assemble(local))
            dec = -float(gf @ p)
        if not np.isfinite(E):
            return X, False, "the energy is not finite (a collapsed triangle)"
        if not np.isfinite(dec):
            return X, False, "Newton direction is not finite (degenerate Hessian)"
        rel_dec = dec / 2 / solver.scale(E)
        if dec / 2 <= tol * solver.scale(E):
            return X, True, f"Newton decrement λ²/2 = {dec / 2:.2e} <= tol·E"
        mesh = solver.mesh if solver.barrier else None
        found = line_search(fun, X, solver.full(p), E, -dec, mesh, min_step=1e-3 if exact else 1e-12)
        if found is None and exact:  # the exact Hessian's model is poor here: back to the projected one
            exact_ok = False
            continue
        log.iters += 1
        if found is None:
            log.record(solver.energy_of(X))
            ok = dec / 2 <= 1e-6 * solver.scale(E)  # at round-off: as good as it gets
            return X, ok, "line search stalled at round-off" if ok else "line search failed"
        step, X, (En, En_true) = found
        log.record(En if En_true is None else En_true)
        if exact and step == 1.0 and dec / 2 <= 10 * tol * solver.scale(E):
            # a full exact Newton step from λ²/2 ≤ 10·tol·E lands within O(λ⁴) of the optimum
            return X, True, f"full Newton step from λ²/2 = {dec / 2:.2e} <= 10·tol·E"
        # triangles on S-ARAP's kink make the last digits converge linearly: three steps in a row that
        # each gain less than tol·E mean the energy has converged
        stalls = stalls + 1 if E - En <= tol * E else 0
        if stalls >= 3:
            return X, True, f"energy stagnated: 3 steps each reduced E by <= {tol:g}·E"
