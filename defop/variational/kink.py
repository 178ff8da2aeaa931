"""Certificates and the smoothing continuation for S-ARAP's kink (Eq. 11 on conformal Jacobians, Σ = σ).

Near a conformal J = s·R, Eq. (11) is ψ ≈ ψ(sR) + φ(a) with φ(a) = r‖a‖ + κ‖a‖²/2 in the anti-conformal part a
of J (:func:`defop.variational.planar.kink_radius`): a second-order cone, so problem (6) near the kink is a smooth
convex part h plus Σ_t A_t φ_t(a_t(X)) with a_t linear in X. Two certificates bound how far a point is above the
local minimum, each by a Fenchel / smoothing argument rather than by a Newton decrement alone:

* :func:`fenchel_gap` at a point where the solver holds the triangles near the kink with their offsets a_t frozen
  (the μ = 0 stage, check 4): with P_t the pull of the rest of the mesh on triangle t (the multiplier of its frozen
  offset), convexity of h gives E(Y) ≥ E(X) − Σ_t [A_t φ_t(a_t) − P_t·a_t + (A_t φ_t)*(P_t)], and
  (A φ)*(P) = (‖P‖ − A r)₊² / (2 A κ). Each term is ≥ 0 (Fenchel–Young) and 0 exactly at equilibrium on the cone
  (a = 0, ‖P‖ ≤ A r) or off it (P = A ∇φ(a)). The first part is the cost of an offset the hold kept; the second
  is the pull beyond what the cone bears (the earlier check 4, which missed the first: it passed points 1.1e-6 to
  2.4e-6 · E above the minimum of a pinned near-conformal star).
* :func:`smoothing_certificate` with the smoothed ψ_μ of :func:`defop.variational.planar.psi_sarap_smooth`:
  ψ − μ ≤ ψ_μ ≤ ψ, so min E_μ ≤ min E and E(X) − min E ≤ [E(X) − E_μ(X)] + [E_μ(X) − min E_μ]; the second bracket
  is the Newton decrement of E_μ (its model is trusted only when the Newton step stays inside each triangle's
  smoothing zone, see :func:`in_zone`). Where many triangles are held their multipliers are not unique (more held
  constraints than free dofs), so :func:`fenchel_gap` with the solver's split can exceed the true gap; this
  certificate needs no split.

The held set itself: :func:`held_on_kink` (which elements sit on a kink set), :func:`kink_pull` (the pull of the
rest of the mesh on them, from a Newton direction) and :func:`kink_gap` (check 4's bound), shared by the
verification (:mod:`.verify`) and the solver's active set (:func:`defop.variational.newton.kink_active_set`).

:func:`refine` is the solver's continuation: while the held point's Fenchel gap is above its target, smooth again
with μ / 100 and re-run the held stage, down to the μ of :func:`certificate_mu`, whose smoothing costs at most
0.3 · verify_tol · E, so that the smoothing certificate holds there.

Measured (seeds 5-8, s = 0.7 / 1.4, noise 1e-6 / 1e-4 of the diagonal, boundary pinned): the frozen offsets reported
11/16 converged, 1.1e-6 to 2.5e-6 above a μ → 1e-13 reference; with the continuation 16/16 converged, within
1.4e-8 of it, and re-solves from 1e-5 moves gain at most 1.4e-8.
"""

from __future__ import annotations

import numpy as np

from . import energies as en
from .inertia import inertia_shift

#: the smallest μ of the continuation (:func:`refine`) and of :func:`smoothing_certificate`
MU_MIN = 1e-13
#: each continuation step divides μ by this
MU_FACTOR = 100.0
#: :func:`certificate_mu`: the smoothing of the certificate may cost this share of check 4's tolerance
CERTIFICATE_SHARE = 0.3


def _forms(S):
    """The closed-form module (:func:`defop.variational.energies.closed_forms`) for singular values S (k, d)."""
    d = np.shape(S)[-1]
    return en.closed_forms(np.empty((0, d, d)))


def fenchel_gap(S, on, areas, pull):
    """Per held element, the Fenchel–Young gap A φ(a) − P·a + (A φ)*(P) ≥ 0 of its frozen offset.

    Parameters
    ----------
    S : (k,d) numpy array
        Singular values of the held elements; the offset a from the kink and its cone cost φ(a) are the closed
        forms' ``kink_offset`` (2D: a = (Σ − σ)/√2 on the anti-conformal mode U Z Vᵀ/√2 of
        :func:`defop.variational.planar.eigensystem`; 3D: per kink set,
        :func:`defop.variational.volumetric.kink_offset`).
    on : (k,) or (k,2) bool numpy array
        Which kink set(s) each element is held on (the closed forms' ``on_kink``).
    areas : (k,) numpy array
        Areas (2D) or volumes (3D).
    pull : (k,d²) numpy array
        The force P the rest of the mesh puts on each mode of the eigensystem (the multiplier of the frozen offset;
        only the held modes, ``kink_stiff_modes``, are read).

    Returns
    -------
    offset : (k,) numpy array
        A φ(a) − P·a, the part from the offset (can be negative; offset + excess ≥ 0).
    excess : (k,) numpy array
        (‖P‖ − A r)₊² / (2 A κ), the gain bound of a pull beyond the cone (‖·‖: the closed forms' ``kink_force``).
    """
    cf = _forms(S)
    a, phi = cf.kink_offset(S, on)
    r, kappa = cf.kink_cone(S, on)
    offset = areas * phi - (pull * a).sum(axis=1)
    excess = np.maximum(cf.kink_force(on, pull) - areas * r, 0.0) ** 2 / (2 * areas * kappa)
    return offset, excess


def offset_cost(S, on, areas):
    """Σ_t A_t φ_t(a_t): what the offsets of the given near-kink elements cost on their cones (no multipliers).

    With ‖P_t‖ ≤ A_t r_t (the pull check), the Fenchel gap of :func:`fenchel_gap` is at most twice this: a cheap
    screen before the Newton system that gives the multipliers.

    Parameters
    ----------
    S : (k,d) numpy array
    on : (k,) or (k,2) bool numpy array
    areas : (k,) numpy array

    Returns
    -------
    cost : float
    """
    return float(areas @ _forms(S).kink_offset(S, on)[1])


def smoothing_gap(S, areas, mu):
    """E(X) − E_μ(X) = Σ_t A_t (ψ − ψ_μ)(J_t) ≥ 0 for S-ARAP (at most μ Σ A_t; only near-kink elements count).

    Parameters
    ----------
    S : (m,d) numpy array
        Signed singular values, descending.
    areas : (m,) numpy array
    mu : float

    Returns
    -------
    gap : float
    """
    smooth, exact = _forms(S).psi_value("sarap", *S.T, mu=mu, both=True)
    ok = np.isfinite(exact)
    return float(areas[ok] @ (exact[ok] - smooth[ok]))


def certificate_mu(E, total_area, tol):
    """The μ of :func:`smoothing_certificate`: its smoothing costs at most ``CERTIFICATE_SHARE`` · tol · E.

    Since 0 ≤ ψ − ψ_μ ≤ μ, E − E_μ ≤ μ Σ A_t; μ = share · tol · E / Σ A_t, within [:data:`MU_MIN`, 1e-5].

    Parameters
    ----------
    E : float
    total_area : float
    tol : float
        Relative tolerance (check 4's ``verify_tol``).

    Returns
    -------
    mu : float
    """
    return float(np.clip(CERTIFICATE_SHARE * tol * E / total_area, MU_MIN, 1e-5))


def smoothing_certificate(stage, decrement, X, E, mu, tol):
    """A bound on E(X) − min E from a smoothed solve started at X (no split of the held set's multipliers).

    With ψ − μ ≤ ψ_μ ≤ ψ (:func:`defop.variational.planar.psi_sarap_smooth`), min E ≥ min E_μ over the basin. A
    Newton stage on E_μ from X ends at X_μ; where the exact Hessian of E_μ there has no negative pivot, its Newton
    decrement λ²/2 bounds E_μ(X_μ) − min E_μ (the quadratic model, as check 4 itself assumes), so
    E(X) − min E ≤ E(X) − E_μ(X_μ) + λ²/2. At a minimum of E this is at most E − E_μ ≤ μ Σ A_t (:func:`certificate_mu`)
    plus the stage's tolerance; at a point whose held offsets cost energy, the smoothed solve finds that energy.

    Parameters
    ----------
    stage : callable
        ``stage(X, mu, t) -> (X, converged, reason)``: a Newton stage on E_μ to decrement tolerance t.
    decrement : callable
        ``decrement(X, mu) -> (E_mu, half_decrement, negative)``: E_μ(X), λ²/2 of its exact Hessian, and that
        Hessian's number of negative pivots (:func:`newton_decrement`).
    X : (n,d) numpy array
    E : float
        E(X).
    mu : float
    tol : float
        Check 4's relative tolerance; the stage runs to t = tol / 100.

    Returns
    -------
    bound : float
        +inf when the smoothed stage did not converge or its Hessian is not positive definite there.
    """
    Xm, ok, _ = stage(X, mu, tol / 100)
    if not ok:
        return np.inf
    E_mu, dec, negative = decrement(Xm, mu)
    if negative or not (np.isfinite(dec) and dec >= 0):
        return np.inf
    return max(E - E_mu + dec, 0.0)


def newton_decrement(solver, X, mu):
    """E_μ(X), the Newton decrement λ²/2 of its exact reduced Hessian and that Hessian's negative pivots, its diagonal
    shifted by the one policy of :func:`defop.variational.inertia.inertia_shift`.

    Parameters
    ----------
    solver : defop.variational.solver.Solver
        Its ``_grad_hess``, ``_newton_direction``, ``free`` and ``_hess.inertia()``.
    X : (n,d) numpy array
    mu : float

    Returns
    -------
    E_mu : float
    half_decrement : float
    negative : int or None
    """
    E_mu, g, data, _ = solver.grad_hess(X, mu, project=False)
    gf = g[solver.free]
    p = solver.newton_direction(gf, data, rel_shift=inertia_shift(solver, data))
    return E_mu, -float(gf @ p) / 2, solver.hessian.inertia()


def refine(stage, held, certificate, X, mu, target, mu_min):
    """The smoothing continuation around the held μ = 0 stage, until the held point's gap is below ``target``.

    Parameters
    ----------
    stage : callable
        ``stage(X, mu) -> (X, converged, reason)``: a Newton stage on E_μ.
    held : callable
        ``held(X) -> (X, converged, reason)``: the μ = 0 stage with the held set (and its releases).
    certificate : callable
        ``certificate(X) -> float``: the bound on (E(X) − min E) / E at a held point (:func:`fenchel_gap` summed).
    X : (n,d) numpy array
        The converged point of the last smoothing stage.
    mu : float
        Its μ (0 when there was none: no continuation).
    target : float
        Bound (relative, as ``certificate``) at which to stop.
    mu_min : float
        The smallest μ to go to (:func:`certificate_mu`: where :func:`smoothing_certificate` certifies).

    Returns
    -------
    X, converged, reason
        As :func:`defop.variational.newton.newton_stage`; ``reason`` notes the extra stages.
    """
    Xh, converged, reason = held(X)
    extra = 0
    while converged and mu > mu_min and certificate(Xh) > target:
        mu = max(mu / MU_FACTOR, mu_min)
        X, ok, why = stage(Xh, mu)
        if not ok:
            return X, ok, why
        Xh, converged, reason = held(X)
        extra += 1
    if extra:
        reason += f" (smoothing continued to μ = {mu:.0e})"
    return Xh, converged, reason


def kink_gap(solver, X, target):
    """Check 4's bound on (E(X) − min E) / E from the elements held on S-ARAP's kink
    (:func:`kink_pull`, :func:`fenchel_gap`).

    Offsets too small to matter (A φ(a) − P·a ≤ 2 A φ(a) while ‖P‖ ≤ A r, which the releases of
    :func:`defop.variational.newton.kink_active_set` ensure; :func:`defop.variational.verify.verify_point` checks the
    pull itself) are screened without a Newton system: below ``target`` the screen is returned. The Newton system's
    diagonal shift is :func:`defop.variational.inertia.inertia_shift`'s.
    """
    _, S, on, held = held_on_kink(solver, X, solver.kink_threshold)
    screen = 2 * offset_cost(S[held], on[held], solver.mesh.areas[held]) / solver.scale(solver.energy_of(X))
    if screen <= target:
        return screen
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=solver.kink_threshold)
    p = solver.newton_direction(g[solver.free], data, rel_shift=inertia_shift(solver, data))
    gain, _, _, _, offset = kink_pull(solver, X, local, p, solver.kink_threshold)
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
        (:func:`fenchel_gap`); ``gain + offset`` bounds E(X) − min E.
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
    offset, gains = fenchel_gap(S, on, A, pull)
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
