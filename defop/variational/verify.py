"""The five checks behind ``converged``: a verified local minimum of problem (6).

At the returned X, with the handles written onto their targets: (1) the energy is finite; (2) every handle sits
on its target to ``HANDLE_TOL`` of the bounding-box diagonal; (3) for barrier energies, no element is flipped or
collapsed; (4) the Newton decrement of the true energy (Eq. 10 / 11, μ = 0; at S-ARAP's kink, its conformal
part) is small, and the S-ARAP triangles held on the kink are in equilibrium on its cone up to ``verify_tol`` · E: a
Fenchel bound on what their offsets and any pull beyond the cone cost (:func:`kink_pull`,
:func:`defop.variational.kink.fenchel_gap`), or, where that bound is loose, a smoothed solve from X
(:func:`defop.variational.kink.smoothing_certificate`); (5) the exact reduced Hessian has no negative
eigenvalue (beyond an ``INERTIA_SHIFT`` relative shift of the median diagonal, :func:`inertia_shift`), read from
the inertia of its LDLᵀ factorisation (Sylvester's law: the signs of D). :class:`Verification` names the check
that failed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..geometry.mesh import ELEMENT
from . import energies as en
from . import kink
from .problem import count_flips

#: handles must sit on their targets to this fraction of the bounding-box diagonal (check 2)
HANDLE_TOL = 1e-12
#: relative diagonal shift under which a negative Hessian eigenvalue counts as round-off (check 5)
INERTIA_SHIFT = 1e-8
#: check 5's shift is at least this many units of round-off of the largest diagonal entry (:func:`inertia_shift`)
ROUNDOFF = 100.0
#: S-ARAP triangles with Σ − σ ≤ KINK · Σ sit on Eq. (11)'s kink for check 4
#: (:func:`defop.variational.planar.eigensystem`)
KINK = 1e-4
#: iteration budget of the smoothed solve behind check 4's smoothing certificate
#: (:func:`defop.variational.kink.smoothing_certificate`)
CERTIFICATE_ITERATIONS = 50


@dataclasses.dataclass
class Verification:
    """Outcome of :func:`verify_point`: ``ok``, the first failed check (``failed``, "" if none) and why."""

    ok: bool
    failed: str
    reason: str
    energy: float
    decrement: float = np.nan
    negative: int = 0
    #: check "kink" only: the (n, d) direction that pulls the overloaded triangles off Eq. (11)'s kink
    kink: np.ndarray | None = dataclasses.field(default=None, repr=False)


def verify_point(solver, X, T, tol=None):
    """The five checks behind ``converged``, at X (handles already on their targets).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    X : (n, d) numpy array
    T : (u, d) numpy array
        Targets per unique handle (:meth:`~defop.variational.problem.ReducedProblem.targets_of`).
    tol : float, optional
        Check 4's tolerance (default ``solver.verify_tol``).

    Returns
    -------
    check : Verification
        ``failed`` is one of "energy", "handles", "flips", "saddle", "decrement", "kink" (or "").
    """
    tol = solver.verify_tol if tol is None else tol
    mesh = solver.mesh
    E = solver.energy_of(X)
    flips = count_flips(mesh, X)
    el = ELEMENT[mesh.dim]
    if not np.isfinite(E):
        return Verification(False, "energy", f"energy is not finite (E = {E}, {flips} flipped/collapsed {el}(s))", E)
    err = float(np.abs(X[solver.handles] - T).max()) / mesh.bbox_diagonal
    if not err <= HANDLE_TOL:
        return Verification(False, "handles", f"a handle is {err:.2e} of the diagonal off its target", E)
    if solver.barrier and flips:
        return Verification(False, "flips", f"{flips} flipped or collapsed {el}(s)", E)
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=solver._kink)  # true energy, exact Hessian
    gf = g[solver.free]
    p = solver.newton_direction(gf, data, rel_shift=inertia_shift(solver, data))
    negative = solver.hessian.inertia()
    dec = -float(gf @ p) / 2
    if negative:
        why = f"saddle point: the reduced Hessian has {negative} negative eigenvalue(s)"
        return Verification(False, "saddle", why, E, dec, negative)
    if not (np.isfinite(dec) and dec <= tol * solver.scale(E)):
        why = f"the true energy's Newton decrement λ²/2 = {dec:.2e} > {tol:g}·E"
        return Verification(False, "decrement", why, E, dec)
    if solver.energy == "sarap":
        gain, worst, D, _, offset = kink_pull(solver, X, local, p, solver._kink)
        bound = gain + offset
        if bound > tol * solver.scale(E):
            cert = kink.smoothing_certificate(
                lambda Y, m, t: _certificate_stage(solver, Y, t, m),
                lambda Y, m: kink.newton_decrement(solver, Y, m, INERTIA_SHIFT),
                X,
                E,
                kink.certificate_mu(E, mesh.areas.sum(), tol),
                tol,
            )
            if cert > tol * solver.scale(E):
                why = (
                    "not a minimum at Eq. (11)'s kink: "
                    + (
                        f"{el} {worst[0]} is pulled off it by {worst[1]:.4g} times the force its cone bears; "
                        if worst
                        else "the held elements' offsets from it cost "
                    )
                    + f"up to {bound:.2e} > {tol:g}·E (smoothing bound {cert:.2e})"
                )
                return Verification(False, "kink", why, E, dec, 0, D)
    return Verification(True, "", "", E, dec, 0)


def inertia_shift(solver, data):
    """Check 5's diagonal shift, as the share of the mean |diagonal| that ``ReducedHessian.matrix`` takes.

    ``INERTIA_SHIFT`` of the median |diagonal|, at least ``ROUNDOFF`` · ε · max|diagonal| and at most
    ``INERTIA_SHIFT`` of the mean. The mean alone is dominated by the stiff held modes of S-ARAP triangles on the
    kink: at the bar's S-shaped saddle (handle pushed in by 0.3, 3 held triangles) the mean |diagonal| was 2.6e7
    against a median of 8.8, so a shift of 0.26 hid the held Hessian's eigenvalue −1.9e-3 and check 5 accepted
    the saddle as a minimum (tests/test_saddle.py).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    data : (nnz,) numpy array
        Values of the exact reduced Hessian (its ``hessian`` pattern).

    Returns
    -------
    rel_shift : float
    """
    d = np.abs(data[solver.hessian._diag])
    mean = max(float(d.mean()), 1e-300)
    shift = max(INERTIA_SHIFT * float(np.median(d)), ROUNDOFF * np.finfo(float).eps * float(d.max()))
    return min(shift, INERTIA_SHIFT * mean) / mean


def _certificate_stage(solver, X, tol, mu):
    """One smoothed Newton stage on a fresh iteration budget (for :func:`.kink.smoothing_certificate`)."""
    from .newton import Log, newton_stage  # newton imports this module

    return newton_stage(solver, Log(CERTIFICATE_ITERATIONS), X, tol, mu)


def kink_gap(solver, X, target):
    """Check 4's bound on (E(X) − min E) / E from the elements held on S-ARAP's kink
    (:func:`kink_pull`, :func:`defop.variational.kink.fenchel_gap`).

    Offsets too small to matter (A φ(a) − P·a ≤ 2 A φ(a) while ‖P‖ ≤ A r, which the releases of
    :func:`defop.variational.newton.kink_active_set` ensure; :func:`verify_point` checks the pull itself) are screened
    without a Newton system: below ``target`` the screen is returned.
    """
    _, S, on, held = held_on_kink(solver, X, solver._kink)
    screen = 2 * kink.offset_cost(S[held], on[held], solver.mesh.areas[held]) / solver.scale(solver.energy_of(X))
    if screen <= target:
        return screen
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=solver._kink)
    p = solver.newton_direction(g[solver.free], data, rel_shift=INERTIA_SHIFT)
    gain, _, _, _, offset = kink_pull(solver, X, local, p, solver._kink)
    return (gain + offset) / solver.scale(E)


def held_on_kink(solver, X, hold):
    """Singular values, kink sets and held elements of S-ARAP at X (the closed forms' ``svd_frame``, ``on_kink``).

    Returns
    -------
    cf : module
        :func:`defop.variational.energies.closed_forms` of the Jacobians.
    S : (m,d) numpy array
    on : (m,) or (m,2) bool numpy array
        2D: on Eq. (11)'s kink Σ = σ; 3D: on σ₁ = σ₂ and on σ₂ = σ₃ (:func:`defop.variational.volumetric.on_kink`).
    held : (m,) bool numpy array
        On any kink set.
    """
    J = solver.mesh.jacobians(X)
    cf = en.closed_forms(J)
    S = cf.svd_frame(J)[0]
    on = cf.on_kink(S, hold)
    return cf, S, on, on.reshape(len(S), -1).any(axis=1)


def kink_pull(solver, X, local, p, hold):
    """S-ARAP elements held on a kink (check 4) that the rest of the mesh pulls off it.

    Check 4 holds an element on a kink set (the closed forms' ``on_kink``): its anti-conformal modes there
    (``kink_stiff_modes``; 2D: modes 1 and 3 of :func:`defop.variational.planar.eigensystem`) are stiff, so in
    the Newton system K p = −g their amplitudes times their stiffness are the force F_t the rest of the mesh
    puts on them. There ψ is a cone (``kink_cone``, :func:`defop.variational.planar.kink_radius`): the element is in
    equilibrium only if ‖F_t‖ ≤ A_t r_t (‖·‖: ``kink_force``; 2D the Euclidean norm, 3D at σ₁ = σ₂ = σ₃ a dual
    norm, :func:`defop.variational.volumetric.kink_force`). An element pulled harder moves off the kink, and the
    quadratic model with its own branch curvature κ_t bounds the gain by (‖F_t‖ − A_t r_t)² / (2 A_t κ_t) when the
    rest is convex.

    Returns
    -------
    gain : float
        Σ_t of that bound over the overloaded elements (0 if none).
    worst : tuple
        (element, ‖F_t‖ / (A_t r_t)) of the largest bound.
    D : (n,d) numpy array or None
        Descent direction: each overloaded element's held modes moved along its force, by the
        model's amplitude (‖F_t‖ − A_t r_t)/(A_t κ_t); zero at the handles.
    pulled : (k,) int numpy array
        The overloaded elements.
    offset : float
        Σ_t A_t φ_t(a_t) − P_t·a_t over the held elements (at least 0): what their offsets cost
        (:func:`defop.variational.kink.fenchel_gap`); ``gain + offset`` bounds E(X) − min E.
    """
    cf, S, on, held = held_on_kink(solver, X, hold)
    idx = np.flatnonzero(held)
    if not len(idx):
        return 0.0, None, None, idx, 0.0
    S, on = S[idx], on[idx]
    stiff = cf.kink_stiff_modes(on)
    W, lamA = local[0][idx], local[1][idx]
    dofs = solver.hessian.dofs[idx]
    amp = np.einsum("tdk,td->tk", W, solver.full(p).ravel()[dofs]) * stiff  # held-mode amplitudes of the step
    pull = lamA * amp
    force = cf.kink_force(on, pull)
    A = solver.mesh.areas[idx]
    r, kappa = cf.kink_cone(S, on)
    offset, gains = kink.fenchel_gap(S, on, A, pull)
    offset = max(float(offset.sum()), 0.0)
    excess = np.maximum(force - A * r, 0.0)
    if not gains.any():
        return 0.0, None, None, idx[:0], offset
    k = int(np.argmax(gains))
    u = amp * (excess / (A * kappa) / np.maximum(cf.kink_force(on, amp), 1e-300))[:, None]
    d = X.shape[1]
    D = np.bincount(dofs.ravel(), np.einsum("tdk,tk->td", W, u).ravel(), minlength=d * solver.mesh.n_vertices)
    D = D.reshape(-1, d)
    D[solver.handles] = 0.0
    return float(gains.sum()), (int(idx[k]), float(force[k] / (A[k] * r[k]))), D, idx[gains > 0], offset
