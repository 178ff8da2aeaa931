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


def newton_decrement(solver, X, mu, shift):
    """E_μ(X), the Newton decrement λ²/2 of its exact reduced Hessian and that Hessian's negative pivots.

    Parameters
    ----------
    solver : defop.variational.solver.Solver
        Its ``_grad_hess``, ``_newton_direction``, ``free`` and ``_hess.inertia()``.
    X : (n,d) numpy array
    mu : float
    shift : float
        Relative diagonal shift of the factorisation (the solver's ``INERTIA_SHIFT``).

    Returns
    -------
    E_mu : float
    half_decrement : float
    negative : int or None
    """
    E_mu, g, data, _ = solver.grad_hess(X, mu, project=False)
    gf = g[solver.free]
    p = solver.newton_direction(gf, data, rel_shift=shift)
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
