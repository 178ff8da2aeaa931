"""The 2×2 closed forms behind :mod:`defop.variational.energies` (d = 2: triangles).

For an isotropic ψ of the *signed* singular values Σ ≥ |σ| of a 2×2 Jacobian (σ < 0 when det J < 0): the signed
SVD in closed form, ψ and its derivatives in (Σ, σ), the gradient ∂ψ/∂J = U diag(ψ_Σ, ψ_σ) Vᵀ, and a positive
semi-definite projected Hessian from the analytic eigensystem of isotropic 2D energies (Smith, de Goes & Kim
2019): the twist mode U[[0,−1],[1,0]]Vᵀ/√2 with eigenvalue (ψ_Σ+ψ_σ)/(Σ+σ), the flip mode U[[0,1],[1,0]]Vᵀ/√2
with (ψ_Σ−ψ_σ)/(Σ−σ), and two scaling modes U diag(e_k) Vᵀ from the 2×2 Hessian of ψ in (Σ, σ). Negative
eigenvalues are clamped to zero. Matrices are flattened row-major: vec(J) = [J00, J01, J10, J11], as in
``Mesh.jacobian_operator``. Also S-ARAP's kink (Eq. 11 on conformal J) and the flip-free step of Smith &
Schaefer (2015), the smallest positive root of the quadratic det(J + t·dJ).

:mod:`defop.variational.volumetric` has the same functions for 3×3 Jacobians; the face in
:mod:`defop.variational.energies` picks one by ``J.shape[-1]``. The energies are validated there.
"""

from __future__ import annotations

import numpy as np

from . import smoothed_max
from .definitions import EXP_SCALE, MAX_POWER


def _rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    R = np.empty(angle.shape + (2, 2))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1] = c, -s, s, c
    return R


def _jacobians(J):
    """J as a float (m,2,2) array; a (2,2) matrix or (m,3,3) was indexed silently (its top-left 2×2 used)."""
    J = np.asarray(J, dtype=float)
    if J.ndim != 3 or J.shape[1:] != (2, 2):
        raise ValueError(f"J must be an (m,2,2) array of 2×2 Jacobians, got shape {J.shape}")
    return J


def signed_svd(J):
    """Signed SVD of 2×2 matrices in closed form: J = U diag(Σ, σ) Vᵀ with U, V rotations.

    Parameters
    ----------
    J : (m,2,2) numpy array

    Returns
    -------
    U : (m,2,2) numpy array
        Rotations (det +1).
    S : (m,2) numpy array
        ``S[:,0] = Σ >= |σ| = |S[:,1]|``; σ < 0 exactly when det J < 0.
    V : (m,2,2) numpy array
        Rotations (det +1).

    Notes
    -----
    With E=(a+d)/2, F=(a−d)/2, G=(c+b)/2, H=(c−b)/2 for J = [[a,b],[c,d]]: Σ = √(E²+H²) + √(F²+G²),
    σ = √(E²+H²) − √(F²+G²), U = R(φ), V = R(−θ) with φ = (atan2(H,E)+atan2(G,F))/2 and
    θ = (atan2(H,E)−atan2(G,F))/2. Working with rotations avoids the sign fix-ups of a general
    SVD (flipping the second column of both U and V when both have det −1).
    """
    J = _jacobians(J)
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    Qn, Rn = np.hypot(E, H), np.hypot(F, G)
    a1, a2 = np.arctan2(G, F), np.arctan2(H, E)
    theta, phi = (a2 - a1) / 2, (a2 + a1) / 2
    S = np.stack([Qn + Rn, Qn - Rn], axis=-1)
    return _rot(phi), S, _rot(-theta)


def svd_frame(J):
    """Signed singular values and the rotation/reflection frame of 2×2 matrices, without trigonometry.

    With α = φ+θ and β = φ−θ the angles of :func:`signed_svd` (U = R(φ), Vᵀ = R(θ)), every
    U diag(d1, d2) Vᵀ = (d1+d2)/2 · R(α) + (d1−d2)/2 · R(β)Z, Z = diag(1, −1); R(α) and R(β)Z are
    read off J directly: cos α = E/|(E,H)|, sin α = H/|(E,H)|, cos β = F/|(F,G)|, sin β = G/|(F,G)|.

    Returns
    -------
    S : (m,2) numpy array
        Σ ≥ |σ|, σ < 0 when det J < 0.
    ca, sa, cb, sb : (m,) numpy arrays
        cos α, sin α, cos β, sin β (β = 0 for conformal J, where it is arbitrary).
    """
    J = _jacobians(J)
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    Qn, Rn = np.hypot(E, H), np.hypot(F, G)
    with np.errstate(divide="ignore", invalid="ignore"):
        ca = np.where(Qn > 0, E / Qn, 1.0)
        sa = np.where(Qn > 0, H / Qn, 0.0)
        cb = np.where(Rn > 0, F / Rn, 1.0)
        sb = np.where(Rn > 0, G / Rn, 0.0)
    return np.stack([Qn + Rn, Qn - Rn], axis=-1), ca, sa, cb, sb


def psi_sarap_smooth(t1, t2, ok, mu):
    """S-ARAP as a smooth maximum of its two orderings, for Newton.

    With Σ ≥ σ, Eq. (11) equals max(f, g) where f = (σ1−1)² + (1/σ2−1)² and g = (σ2−1)² + (1/σ1−1)²
    (the same expression with the singular values swapped). That maximum has a kink on the conformal
    matrices Σ = σ ≠ 1, where Newton stalls. ψ_μ = (f+g)/2 + √(((f−g)/2)² + μ²) − μ is smooth,
    symmetric in (σ1, σ2), and within μ of Eq. (11): ψ − μ ≤ ψ_μ ≤ ψ. (With Σ ≥ σ > 0, f ≥ g, so
    max(f, g) is exactly Eq. (11).)
    """
    f = (t1 - 1) ** 2 + (1 / t2 - 1) ** 2
    g = (t2 - 1) ** 2 + (1 / t1 - 1) ** 2
    f1, f2 = 2 * (t1 - 1), 2 * (t2 - 1) / t2**3
    g1, g2 = 2 * (t1 - 1) / t1**3, 2 * (t2 - 1)
    f11, f22 = np.full_like(t1, 2.0), 6 / t2**4 - 4 / t2**3
    g11, g22 = 6 / t1**4 - 4 / t1**3, np.full_like(t1, 2.0)
    a, b, *ab = smoothed_max.half_sums(f, g, f1, f2, g1, g2, f11, f22, g11, g22)
    r = np.sqrt(b * b + mu * mu)
    w, c = b / r, mu * mu / r**3
    psi = np.where(ok, a + r - mu, np.inf)
    p1, p2, p11, p22, p12, twist = smoothed_max.derivatives(t1, t2, *ab, w, c)
    gap = t1 - t2
    with np.errstate(divide="ignore", invalid="ignore"):
        flip = np.where(gap > 1e-6 * t1, (p1 - p2) / gap, p11 - p12)
    return psi, p1, p2, p11, p22, p12, twist, flip


def _twist_flip(t1, t2, p1, p2, p11, p12):
    """Twist and flip eigenvalues (p1+p2)/(t1+t2), (p1−p2)/(t1−t2) of an energy symmetric in (t1, t2) and smooth
    across t1 = t2, where the flip eigenvalue's limit is p11 − p12."""
    gap = t1 - t2
    with np.errstate(divide="ignore", invalid="ignore"):
        flip = np.where(gap > 1e-6 * t1, (p1 - p2) / gap, p11 - p12)
    return (p1 + p2) / (t1 + t2), flip


def _psi_isometric_max(t1, t2, p=None):
    """ψ = (t1ᵖ + t2ᵖ + t1⁻ᵖ + t2⁻ᵖ)^(2/p) − 4^(2/p) and its derivatives (ψ, ψ1, ψ2, ψ11, ψ22, ψ12), t1, t2 > 0.

    With D = (Σ xᵢᵖ)^(1/p) (x = t1, t2, 1/t1, 1/t2), aᵢ = (tᵢ/D)ᵖ and bᵢ = (1/(tᵢD))ᵖ (both ≤ 1, so no
    overflow before D itself does): ψᵢ = 2D²(aᵢ − bᵢ)/tᵢ, ψᵢᵢ = 2D²[(2−p)(aᵢ − bᵢ)² + (p−1)aᵢ + (p+1)bᵢ]/tᵢ²,
    ψ12 = 2(2−p)D²(a1 − b1)(a2 − b2)/(t1 t2).
    """
    p = MAX_POWER if p is None else p
    x = np.stack([t1, t2, 1 / t1, 1 / t2])
    top = x.max(axis=0)
    D = top * (((x / top) ** p).sum(axis=0)) ** (1 / p)
    a1, a2, b1, b2 = (t1 / D) ** p, (t2 / D) ** p, (1 / (t1 * D)) ** p, (1 / (t2 * D)) ** p
    D2 = D * D
    psi = D2 - 4 ** (2 / p)
    p1, p2 = 2 * D2 * (a1 - b1) / t1, 2 * D2 * (a2 - b2) / t2
    p11 = 2 * D2 * ((2 - p) * (a1 - b1) ** 2 + (p - 1) * a1 + (p + 1) * b1) / t1**2
    p22 = 2 * D2 * ((2 - p) * (a2 - b2) ** 2 + (p - 1) * a2 + (p + 1) * b2) / t2**2
    p12 = 2 * (2 - p) * D2 * (a1 - b1) * (a2 - b2) / (t1 * t2)
    return psi, p1, p2, p11, p22, p12


def _psi_isometric_exp(t1, t2, s=None):
    """ψ = exp(s (t1² + t2² + t1⁻² + t2⁻² − 4)) − 1 and its derivatives (ψ, ψ1, ψ2, ψ11, ψ22, ψ12), t1, t2 > 0."""
    s = EXP_SCALE if s is None else s
    with np.errstate(over="ignore"):
        e = np.exp(s * (t1**2 + t2**2 + t1**-2 + t2**-2 - 4))
    d1, d2 = 2 * t1 - 2 / t1**3, 2 * t2 - 2 / t2**3
    p11 = s * e * (2 + 6 / t1**4 + s * d1 * d1)
    p22 = s * e * (2 + 6 / t2**4 + s * d2 * d2)
    return e - 1, s * e * d1, s * e * d2, p11, p22, s * s * e * d1 * d2


_SMOOTH_ISOTROPIC = {"isometric_max": _psi_isometric_max, "isometric_exp": _psi_isometric_exp}


def psi_derivatives(energy, s1, s2, mu=0.0):
    """ψ and its derivatives in the signed singular values: (ψ, ψ1, ψ2, ψ11, ψ22, ψ12, twist, flip).

    ``mu > 0`` selects the smoothed S-ARAP of :func:`psi_sarap_smooth` (ignored by the others).
    """
    inf = np.inf
    if energy == "arap":
        psi = (s1 - 1) ** 2 + (s2 - 1) ** 2
        p1, p2 = 2 * (s1 - 1), 2 * (s2 - 1)
        p11 = p22 = np.full_like(s1, 2.0)
        p12 = np.zeros_like(s1)
        ssum = s1 + s2
        with np.errstate(divide="ignore", invalid="ignore"):
            twist = np.where(np.abs(ssum) > 1e-12, 2 - 4 / ssum, -inf)  # -inf → clamped to 0
        flip = np.full_like(s1, 2.0)
        return psi, p1, p2, p11, p22, p12, twist, flip
    ok = s2 > 0
    t1 = np.where(ok, s1, 1.0)
    t2 = np.where(ok, s2, 1.0)
    if energy == "sarap" and mu > 0:
        return psi_sarap_smooth(t1, t2, ok, mu)
    if energy == "sarap":
        psi = np.where(ok, (t1 - 1) ** 2 + (1 / t2 - 1) ** 2, inf)
        p1 = 2 * (t1 - 1)
        p2 = 2 * (t2 - 1) / t2**3
        p11 = np.full_like(t1, 2.0)
        p22 = 6 / t2**4 - 4 / t2**3
        p12 = np.zeros_like(t1)
        twist = (p1 + p2) / (t1 + t2)
        gap = t1 - t2
        # the ordered-σ energy is not C¹ across Σ = σ ≠ 1: the flip eigenvalue grows like 1/(Σ−σ); cap it
        num = p1 - p2
        cap = 1e4 * (1 + p11 + np.abs(p22))
        with np.errstate(divide="ignore", invalid="ignore"):
            flip = np.where(gap > 1e-8, num / gap, np.where(np.abs(num) > 1e-10, cap, (p11 + p22) / 2))
        flip = np.minimum(flip, cap)
        return psi, p1, p2, p11, p22, p12, twist, flip
    if energy == "isometric":
        psi = np.where(ok, t1**2 + t2**2 + t1**-2 + t2**-2, inf)
        p1, p2 = 2 * t1 - 2 / t1**3, 2 * t2 - 2 / t2**3
        p11, p22 = 2 + 6 / t1**4, 2 + 6 / t2**4
        p12 = np.zeros_like(t1)
        den = (t1 * t2) ** 3
        twist = 2 - 2 * (t1**2 - t1 * t2 + t2**2) / den
        flip = 2 + 2 * (t1**2 + t1 * t2 + t2**2) / den
        return psi, p1, p2, p11, p22, p12, twist, flip
    if energy in _SMOOTH_ISOTROPIC:
        psi, p1, p2, p11, p22, p12 = _SMOOTH_ISOTROPIC[energy](t1, t2)
        return (np.where(ok, psi, inf), p1, p2, p11, p22, p12, *_twist_flip(t1, t2, p1, p2, p11, p12))
    raise ValueError(f"unknown energy {energy!r}")


def psi_value(energy, s1, s2, mu=0.0, both=False):
    """ψ alone (no derivatives), for line searches; ``both=True`` returns (ψ_μ, ψ) for S-ARAP."""
    if energy == "arap":
        psi = (s1 - 1) ** 2 + (s2 - 1) ** 2
        return (psi, psi) if both else psi
    ok = s2 > 0
    t1 = np.where(ok, s1, 1.0)
    t2 = np.where(ok, s2, 1.0)
    if energy == "sarap":
        f = (t1 - 1) ** 2 + (1 / t2 - 1) ** 2
        g = (t2 - 1) ** 2 + (1 / t1 - 1) ** 2
        a, b = (f + g) / 2, (f - g) / 2
        exact = np.where(ok, a + np.abs(b), np.inf)  # = Eq. (11): with Σ ≥ σ > 0, f ≥ g
        smooth = np.where(ok, a + np.sqrt(b * b + mu * mu) - mu, np.inf) if mu > 0 else exact
        return (smooth, exact) if both else smooth
    if energy in _SMOOTH_ISOTROPIC:
        psi = np.where(ok, _SMOOTH_ISOTROPIC[energy](t1, t2)[0], np.inf)
        return (psi, psi) if both else psi
    psi = np.where(ok, t1**2 + t2**2 + t1**-2 + t2**-2, np.inf)
    return (psi, psi) if both else psi


def density(J, energy, mu=0.0, both=False):
    """ψ(J_t) per triangle; ``both=True``: (ψ_μ, ψ) (S-ARAP smoothed by μ, and Eq. 11 itself).

    Parameters
    ----------
    J : (m,2,2) numpy array
    energy : str
        One of :data:`ENERGIES`.

    Returns
    -------
    psi : (m,) numpy array
        +inf on flipped triangles for the barrier energies.
    """
    S = svd_frame(J)[0]
    return psi_value(energy, S[:, 0], S[:, 1], mu, both)


def gradient(J, energy, mu=0.0):
    """∂ψ/∂J per triangle: U diag(ψ_Σ, ψ_σ) Vᵀ.

    Parameters
    ----------
    J : (m,2,2) numpy array
    energy : str

    Returns
    -------
    psi : (m,) numpy array
    dpsi : (m,2,2) numpy array
        Only meaningful where ψ is finite.
    """
    U, S, V = signed_svd(J)
    psi, p1, p2 = psi_derivatives(energy, S[:, 0], S[:, 1], mu)[:3]
    return psi, np.matmul(U * np.stack([p1, p2], -1)[:, None, :], np.swapaxes(V, 1, 2))


def kink_radius(S):
    """Slope r and branch curvature κ of S-ARAP (Eq. 11) across its kink, for triangles near Σ = σ.

    On a conformal J = s·R, Eq. (11) is a cone in the anti-conformal part a of J (its coordinates on the two
    unit modes U Z Vᵀ/√2 and the flip of :func:`eigensystem`): moving by a opens the gap Σ − σ = √2‖a‖, and
    ψ = max(f, g) (:func:`psi_sarap_smooth`) grows like ψ(sR) + r‖a‖ + κ‖a‖²/2 along a ray, with

        r = √2 (s − 1)(1 − s⁻³) ≥ 0,    κ = 1 + 3 s⁻⁴ − 2 s⁻³ ≥ 15/16,

    the slope |∂(f − g)/∂a|/2 and the curvature (f_ΣΣ + f_σσ)/2 of the branch f. The subdifferential of the cone
    is the disk ‖F‖ ≤ r: a held triangle is in equilibrium only if the force on a stays inside it.

    Parameters
    ----------
    S : (m,2) numpy array
        Singular values Σ ≥ σ > 0; s = (Σ + σ)/2.

    Returns
    -------
    r : (m,) numpy array
    kappa : (m,) numpy array
    """
    s = np.asarray(S, dtype=float).mean(axis=-1)
    return np.sqrt(2.0) * (s - 1) * (1 - s**-3), 1 + 3 * s**-4 - 2 * s**-3


def on_kink(S, kink):
    """Which triangles count as sitting on S-ARAP's kink (the one rule of :func:`eigensystem` and the solver).

    A triangle is on the kink when its gap is within ``kink`` of it, Σ − σ ≤ kink · Σ, and the cone dominates
    there: its slope r exceeds the branch's κ times the offset a = (Σ − σ)/√2 (:func:`kink_radius`).
    Near s = 1 the cone vanishes (r ≈ 3√2 (s − 1)²) and ψ is smooth: such triangles are not held.

    Parameters
    ----------
    S : (m,2) numpy array
        Σ ≥ |σ|.
    kink : float or (m,) numpy array

    Returns
    -------
    on : (m,) bool numpy array
    """
    gap = S[:, 0] - S[:, 1]
    ok = S[:, 1] > 0
    r, kappa = kink_radius(np.where(ok[:, None], S, 1.0))
    return ok & (gap <= kink * S[:, 0]) & (kappa * gap / np.sqrt(2.0) < r)


def kink_stiff_modes(on):
    """Which of the 4 modes of :func:`eigensystem` are held stiff on the kink: the anti-conformal ones, 1 and 3.

    Parameters
    ----------
    on : (m,) bool numpy array
        :func:`on_kink`.

    Returns
    -------
    stiff : (m,4) bool numpy array
    """
    on = np.asarray(on, dtype=bool)
    z = np.zeros_like(on)
    return np.stack([z, on, z, on], axis=-1)


def kink_force(on, F):
    """The size ‖F‖ of the force on the two held modes (:func:`kink_stiff_modes`): equilibrium ⇔ ‖F‖ ≤ A r.

    Parameters
    ----------
    on : (m,) bool numpy array
    F : (m,4) numpy array
        Force on each mode of :func:`eigensystem`.

    Returns
    -------
    norm : (m,) numpy array
        0 where the triangle is not held.
    """
    return np.where(on, np.hypot(F[:, 1], F[:, 3]), 0.0)


def kink_cone(S, on):
    """Slope r and curvature κ of the cone of each held triangle (:func:`kink_radius`; ``on`` is for 3D's sake).

    Returns
    -------
    r, kappa : (m,) numpy arrays
    """
    return kink_radius(S)


def kink_offset(S, on):
    """The offset of held triangles from the kink, a = ((Σ − σ)/√2 on mode 1), and its cone cost φ(a) = r a + κ a²/2.

    Parameters
    ----------
    S : (m,2) numpy array
        Σ ≥ σ > 0.
    on : (m,) bool numpy array

    Returns
    -------
    a : (m,4) numpy array
        Coordinates on the modes of :func:`eigensystem` (held basis; zero on the soft modes).
    phi : (m,) numpy array
    """
    r, kappa = kink_radius(S)
    n = (S[:, 0] - S[:, 1]) / np.sqrt(2.0)
    a = np.zeros((len(S), 4))
    a[:, 1] = n
    return a, r * n + kappa * n * n / 2


def eigensystem(J, energy, project=True, mu=0.0, kink=0.0):
    """ψ, ∂ψ/∂J and the analytic eigensystem of the Hessian ∂²ψ/∂vec(J)² per triangle.

    The eigenmatrices (Smith, de Goes & Kim 2019), orthonormal in vec(J) = [J00, J01, J10, J11]:
    the two scaling modes U diag(cos γ, sin γ) Vᵀ and U diag(−sin γ, cos γ) Vᵀ (γ diagonalises the
    2×2 Hessian of ψ in (Σ, σ)), the twist U[[0,−1],[1,0]]Vᵀ/√2 and the flip U[[0,1],[1,0]]Vᵀ/√2.

    Parameters
    ----------
    J : (m,2,2) numpy array
    energy : str
    project : bool
        Clamp negative eigenvalues to zero (PSD).
    mu : float
        S-ARAP smoothing (see :func:`psi_sarap_smooth`).
    kink : float
        S-ARAP with ``mu = 0`` only: triangles within ``kink`` of Eq. (11)'s kink (:func:`on_kink`) sit on it,
        where ψ is not differentiable: their gradient is the conformal part alone (the subgradient of the
        cone |Σ − σ| that is symmetric in Σ, σ) and the two anti-conformal modes get a curvature 1e8 times
        their scale: their offsets from the kink are frozen. Motion off the kink is not modelled: the solver
        checks that the force on them stays inside the cone (:func:`kink_radius`). A scalar or one threshold
        per triangle.

    Returns
    -------
    psi : (m,) numpy array
    grad : (m,4) numpy array
        vec(∂ψ/∂J).
    lam : (m,4) numpy array
        Eigenvalues (scaling, scaling, twist, flip); non-finite ones are set to 0.
    modes : (m,4,4) numpy array
        ``modes[t, :, k]`` is the k-th unit eigenvector, vec of the eigenmatrix.
    """
    S, ca, sa, cb, sb = svd_frame(J)
    psi, p1, p2, p11, p22, p12, twist, flip = psi_derivatives(energy, S[:, 0], S[:, 1], mu)
    r = 1 / np.sqrt(2)
    e_rot = np.stack([ca, -sa, sa, ca], axis=-1) * r  # vec R(α)/√2
    e_ref = np.stack([cb, sb, sb, -cb], axis=-1) * r  # vec R(β)Z/√2
    e_twist = np.stack([-sa, -ca, ca, -sa], axis=-1) * r  # vec R(α+90°)/√2
    e_flip = np.stack([-sb, cb, cb, sb], axis=-1) * r  # vec R(β+90°)Z/√2
    grad = ((p1 + p2) * r)[:, None] * e_rot + ((p1 - p2) * r)[:, None] * e_ref
    # scaling modes: closed-form eigen-decomposition of the 2x2 Hessian [[ψ11, ψ12], [ψ12, ψ22]] in (Σ, σ)
    p11, p22, p12 = (np.where(np.isfinite(x), x, 0.0) for x in (p11, p22, p12))
    mean, half = (p11 + p22) / 2, (p11 - p22) / 2
    rad = np.hypot(half, p12)
    ang = 0.5 * np.arctan2(2 * p12, p11 - p22)
    c, s_ = np.cos(ang), np.sin(ang)
    s1 = ((c + s_) * r)[:, None] * e_rot + ((c - s_) * r)[:, None] * e_ref  # U diag(c, s) Vᵀ
    s2 = ((c - s_) * r)[:, None] * e_rot - ((c + s_) * r)[:, None] * e_ref  # U diag(−s, c) Vᵀ
    lam = np.stack([mean + rad, mean - rad, np.where(np.isfinite(twist), twist, -np.inf), flip], axis=-1)
    if energy == "sarap" and mu == 0 and np.any(np.asarray(kink) > 0):
        on = on_kink(S, kink)
        if on.any():
            big = 1e8 * (1 + np.abs(p11) + np.abs(p22))
            grad = np.where(on[:, None], ((p1 + p2) * r)[:, None] * e_rot, grad)
            lam = np.where(on[:, None], np.stack([(p11 + p22) / 2, big, lam[:, 2], big], axis=-1), lam)
            s1 = np.where(on[:, None], e_rot, s1)
            s2 = np.where(on[:, None], e_ref, s2)
    if project:
        lam = np.maximum(lam, 0.0)
    lam = np.where(np.isfinite(lam), lam, 0.0)
    return psi, grad, lam, np.stack([s1, s2, e_twist, e_flip], axis=-1)


def max_flip_free_step(J, dJ, safety=0.9):
    """Largest t in (0, 1] such that det(J + s·dJ) > 0 for all s in [0, t) (Smith & Schaefer 2015).

    Per triangle, det(J + t dJ) = det J + t·tr(adj(J) dJ) + t²·det dJ is a quadratic in t; the
    step is ``safety`` times its smallest positive root over all triangles (the linear case
    det dJ = 0 handled), capped at 1.

    Parameters
    ----------
    J, dJ : (m,2,2) numpy arrays
        Current Jacobians (all det > 0) and their change along the search direction.
    safety : float

    Returns
    -------
    t : float
    """
    a = dJ[:, 0, 0] * dJ[:, 1, 1] - dJ[:, 0, 1] * dJ[:, 1, 0]
    b = J[:, 0, 0] * dJ[:, 1, 1] + dJ[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * dJ[:, 1, 0] - dJ[:, 0, 1] * J[:, 1, 0]
    c = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    scale = np.abs(a) + np.abs(b) + np.abs(c)
    lin = np.abs(a) <= 1e-14 * scale
    roots = np.full(len(J), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        # linear: b t + c = 0
        tl = -c / b
        roots = np.where(lin & (tl > 0), tl, roots)
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        # numerically stable quadratic roots
        qq = -0.5 * (b + np.copysign(sq, b))
        r1, r2 = qq / a, c / qq
        for r in (r1, r2):
            roots = np.where(~lin & (disc >= 0) & (r > 0) & (r < roots), r, roots)
    t = float(np.min(roots)) if len(roots) else np.inf
    return min(1.0, safety * t)
