"""The energies of :mod:`defop.variational.energies` on tetrahedra: closed forms for 3×3 Jacobians J (m,3,3).

Same names and signatures as the 2×2 functions (``signed_svd``, ``svd_frame``, ``psi_value``, ``psi_derivatives``,
``density``, ``gradient``, ``eigensystem``, ``hessian``, ``kink_radius``, ``on_kink``, ``kink_stiff_modes``,
``kink_force``, ``kink_cone``, ``kink_offset``, ``max_flip_free_step``), so
one small face can dispatch on ``J.shape[-1]``. Each energy is E(X) = Σ_t vol_t ψ(J_t), an isotropic ψ of the
*signed* singular values σ₁ ≥ σ₂ ≥ |σ₃| (σ₃ < 0 exactly when det J < 0; Irving et al. 2004, Smith et al. 2019):

* ``"arap"``: ψ = Σᵢ (σᵢ − 1)², Eq. (10) with a third term.
* ``"sarap"``: the extension of S-ARAP, Eq. (11), to a middle singular value,

      ψ = (σ₁ − 1)² + ½[(σ₂ − 1)² + (σ₂⁻¹ − 1)²] + (σ₃⁻¹ − 1)²,   σ₁ ≥ σ₂ ≥ σ₃ > 0,  +inf when det J ≤ 0.

  With u(x) = (x − 1)², v(x) = (x⁻¹ − 1)² = u(1/x) and w = u − v (increasing: w' = 2(x − 1)(1 − x⁻³) ≥ 0) it is
  ψ = ½ Σᵢ (u + v)(σᵢ) + ¼ Σ_{i<j} |w(σᵢ) − w(σⱼ)|, a symmetric function whose kinks are σ₁ = σ₂ and σ₂ = σ₃;
  Eq. (11) is ψ₂ = ½ Σᵢ (u + v)(σᵢ) + ½ |w(Σ) − w(σ)| in the same terms. It is also the largest of the six ways to
  give the σᵢ the weights (u, ½(u + v), v). Properties (tests/test_energies_3d.py): ψ(J⁻¹) = ψ(J) exactly;
  ψ − ψ_ARAP = −½ w(σ₂) − w(σ₃) = O(|σ − 1|³) (ARAP to second order at rest); on J = diag(J₂, 1) it equals
  Eq. (11) of J₂ exactly when Σ ≥ 1 ≥ σ, and exceeds it by ½ |w| of the planar singular value on the same side of 1
  as the other (by ½ w(σ) when both stretch, −½ w(Σ) when both shrink; O(|σ − 1|³)).
* ``"isometric"``: the symmetric Dirichlet energy Σᵢ σᵢ² + σᵢ⁻², +inf when det J ≤ 0; its rest value is 6
  (4 in 2D: on diag(J₂, 1) it is the 2D value + 2).
* ``"isometric_max"``: (Σ xᵖ)^(2/p) − 6^(2/p) over x = σᵢ, σᵢ⁻¹ (p = ``MAX_POWER``): ≈ max(σ₁, σ₃⁻¹)² − 1.
* ``"isometric_exp"``: exp(s (Σᵢ σᵢ² + σᵢ⁻² − 6)) − 1 (s = ``EXP_SCALE``): equals the 2D value on diag(J₂, 1).

Scale: the 2D energies are plain sums over the singular values (no ½, no normalisation by the dimension) and these
are too, so a planar deformation diag(J₂, 1) of a unit-thickness slab costs the same as in 2D (ARAP, S-ARAP when
Σ ≥ 1 ≥ σ, ``isometric_exp``) or the same up to the rest value (``isometric``).

Hessians use the analytic eigensystem of isotropic energies (Smith, de Goes & Kim 2019): three scaling modes
U diag(eₖ) Vᵀ from the 3×3 Hessian of ψ in σ, and per pair (i, j) a twist (U(E_ji − E_ij)Vᵀ)/√2 with eigenvalue
(ψᵢ + ψⱼ)/(σᵢ + σⱼ) and a flip (U(E_ij + E_ji)Vᵀ)/√2 with (ψᵢ − ψⱼ)/(σᵢ − σⱼ) (limit ψᵢᵢ − ψᵢⱼ at σᵢ = σⱼ for a
smooth ψ). Matrices are flattened row-major, vec(J) = [J00, J01, J02, J10, …, J22].
"""

from __future__ import annotations

import numpy as np

from .definitions import EXP_SCALE, MAX_POWER, check_energy
from .volumetric_step import STEP_SCREEN, max_flip_free_step  # noqa: F401 (public here too)
from .volumetric_svd import signed_singular_values, signed_svd, svd_frame  # noqa: F401 (public here too)

#: value of ψ at rotations, per energy (3D)
REST_VALUE = {"arap": 0.0, "sarap": 0.0, "isometric": 6.0, "isometric_max": 0.0, "isometric_exp": 0.0}
#: the singular-value pairs (i, j), i < j, of the twist and flip modes, in the order of :func:`eigensystem`
PAIRS = ((0, 1), (0, 2), (1, 2))
#: the two kink sets of S-ARAP, as the pairs that meet there: σ₁ = σ₂ and σ₂ = σ₃
KINK_PAIRS = ((0, 1), (1, 2))
_R2 = np.sqrt(2.0)


def _positive(S):
    """(ok, T): elements with σ₃ > 0 and S with the others replaced by ones (for the barrier energies)."""
    ok = S[:, 2] > 0
    return ok, np.where(ok[:, None], S, 1.0)


def _isometric_max(T, p=None):
    """ψ = (Σ xᵖ)^(2/p) − (2d)^(2/p) over x = T, 1/T and its derivatives (ψ, ∂ψ (m,d), ∂²ψ (m,d,d)), T > 0.

    The 2D closed forms of :mod:`defop.variational.energies` per singular value: with D the p-norm,
    aᵢ = (tᵢ/D)ᵖ, bᵢ = (1/(tᵢD))ᵖ, ψᵢ = 2D²(aᵢ − bᵢ)/tᵢ, ψᵢⱼ = 2(2 − p)D²(aᵢ − bᵢ)(aⱼ − bⱼ)/(tᵢtⱼ) plus
    2D²[(p − 1)aᵢ + (p + 1)bᵢ]/tᵢ² on the diagonal.
    """
    p = MAX_POWER if p is None else p
    x = np.concatenate([T, 1 / T], axis=1)
    top = x.max(axis=1, keepdims=True)
    D = top[:, 0] * (((x / top) ** p).sum(axis=1)) ** (1 / p)
    a, b = (T / D[:, None]) ** p, (1 / (T * D[:, None])) ** p
    D2 = (D * D)[:, None]
    c = (a - b) / T
    d1 = 2 * D2 * c
    d2 = 2 * (2 - p) * D2[:, :, None] * c[:, :, None] * c[:, None, :]
    d2 += np.einsum("mi,ij->mij", 2 * D2 * ((p - 1) * a + (p + 1) * b) / T**2, np.eye(T.shape[1]))
    return D * D - (2.0 * T.shape[1]) ** (2 / p), d1, d2


def _isometric_exp(T, s=None):
    """ψ = exp(s (Σ t² + t⁻² − 2d)) − 1 and (ψ, ∂ψ (m,d), ∂²ψ (m,d,d)), T > 0."""
    s = EXP_SCALE if s is None else s
    with np.errstate(over="ignore"):
        e = np.exp(s * ((T**2 + T**-2).sum(axis=1) - 2 * T.shape[1]))[:, None]
    d = 2 * T - 2 / T**3
    d2 = (s * s * e)[:, :, None] * d[:, :, None] * d[:, None, :]
    d2 += np.einsum("mi,ij->mij", s * e * (2 + 6 / T**4), np.eye(T.shape[1]))
    return e[:, 0] - 1, s * e * d, d2


def _sarap(T, mu):
    """S-ARAP ψ_μ = ½ Σ (u + v)(tᵢ) + ½ Σ_{i<j} h(w(tᵢ) − w(tⱼ)), h(x) = √(x²/4 + μ²) − μ, and its derivatives.

    μ = 0 is the ordered formula of the module docstring (h = |x|/2); on a kink (tᵢ = tⱼ exactly) the gradient is
    the mean over the pair, the subgradient symmetric in the pair. Returns (ψ_μ, ψ, ∂ψ_μ (m,3), ∂²ψ_μ (m,3,3)).
    """
    u, v = (T - 1) ** 2, (1 / T - 1) ** 2
    g1 = (T - 1) * (1 + T**-3)  # (u' + v')/2
    g2 = 1 + 3 * T**-4 - 2 * T**-3  # (u'' + v'')/2
    w, w1, w2 = u - v, 2 * (T - 1) * (1 - T**-3), 2 - 6 * T**-4 + 4 * T**-3
    base = 0.5 * (u + v).sum(axis=1)
    exact, smooth = base.copy(), base.copy()
    d1, d2 = g1.copy(), np.einsum("mi,ij->mij", g2, np.eye(3))
    for i, j in PAIRS:
        x = w[:, i] - w[:, j]
        exact += 0.25 * np.abs(x)
        if mu > 0:
            r = np.sqrt(x * x / 4 + mu * mu)
            h, h1, h2 = r - mu, x / (4 * r), mu * mu / (4 * r**3)
        else:
            h, h1, h2 = np.abs(x) / 2, np.sign(x) / 2, np.zeros_like(x)
        smooth += 0.5 * h
        d1[:, i] += 0.5 * h1 * w1[:, i]
        d1[:, j] -= 0.5 * h1 * w1[:, j]
        d2[:, i, i] += 0.5 * (h2 * w1[:, i] ** 2 + h1 * w2[:, i])
        d2[:, j, j] += 0.5 * (h2 * w1[:, j] ** 2 - h1 * w2[:, j])
        d2[:, i, j] -= 0.5 * h2 * w1[:, i] * w1[:, j]
        d2[:, j, i] = d2[:, i, j]
    return smooth, exact, d1, d2


def _psi_sigma(energy, S, mu):
    """(ψ_μ, ψ, ∂ψ (m,3), ∂²ψ (m,3,3)) in the signed singular values; +inf off the barriers' domain."""
    if energy == "arap":
        psi = ((S - 1) ** 2).sum(axis=1)
        return psi, psi, 2 * (S - 1), np.broadcast_to(2 * np.eye(3), (len(S), 3, 3)).copy()
    ok, T = _positive(S)
    if energy == "sarap":
        smooth, exact, d1, d2 = _sarap(T, mu)
    elif energy == "isometric":
        smooth = exact = (T**2 + T**-2).sum(axis=1)
        d1, d2 = 2 * T - 2 / T**3, np.einsum("mi,ij->mij", 2 + 6 / T**4, np.eye(3))
    else:
        smooth, d1, d2 = {"isometric_max": _isometric_max, "isometric_exp": _isometric_exp}[energy](T)
        exact = smooth
    return np.where(ok, smooth, np.inf), np.where(ok, exact, np.inf), d1, d2


def _twist_flip(energy, S, d1, d2, mu):
    """Twist and flip eigenvalues (m,3) per pair of :data:`PAIRS` (module docstring), with their limits.

    A smooth ψ's flip eigenvalue tends to ψᵢᵢ − ψᵢⱼ as σᵢ → σⱼ. S-ARAP with μ = 0 is not C¹ across its kinks: there
    it grows like 1/(σᵢ − σⱼ) and is capped, as in 2D, at 1e4 (1 + ψᵢᵢ + |ψⱼⱼ|).
    """
    twist, flip = np.empty((len(S), 3)), np.empty((len(S), 3))
    _, T = _positive(S) if energy != "arap" else (None, S)
    for k, (i, j) in enumerate(PAIRS):
        with np.errstate(divide="ignore", invalid="ignore"):  # inf − inf where ψ overflows (isometric_exp)
            ssum, gap, num = T[:, i] + T[:, j], T[:, i] - T[:, j], d1[:, i] - d1[:, j]
            twist[:, k] = np.where(np.abs(ssum) > 1e-12, (d1[:, i] + d1[:, j]) / ssum, -np.inf)  # -inf → 0
            if energy == "sarap" and mu == 0:
                pii, pjj = d2[:, i, i], d2[:, j, j]
                cap = 1e4 * (1 + pii + np.abs(pjj))
                lim = np.where(np.abs(num) > 1e-10, cap, (pii + pjj) / 2)
                flip[:, k] = np.minimum(np.where(gap > 1e-8, num / gap, lim), cap)
            else:
                lim = d2[:, i, i] - d2[:, i, j]
                flip[:, k] = np.where(gap > 1e-6 * np.abs(T[:, i]), num / gap, lim)
    return twist, flip


def psi_derivatives(energy, s1, s2, s3, mu=0.0):
    """ψ and its derivatives in the signed singular values: (ψ, ∂ψ (m,3), ∂²ψ (m,3,3), twist (m,3), flip (m,3)).

    ``mu > 0`` selects the smoothed S-ARAP (``_sarap``: ψ − 3μ/2 ≤ ψ_μ ≤ ψ, one √(b² + μ²) − μ per pair as in
    :func:`defop.variational.energies.psi_sarap_smooth`); ignored by the others. Twist and flip per pair of
    :data:`PAIRS`.
    """
    check_energy(energy)
    S = np.stack(np.broadcast_arrays(*(np.asarray(s, dtype=float) for s in (s1, s2, s3))), axis=-1).reshape(-1, 3)
    psi, _, d1, d2 = _psi_sigma(energy, S, mu)
    return (psi, d1, d2, *_twist_flip(energy, S, d1, d2, mu))


def psi_value(energy, s1, s2, s3, mu=0.0, both=False):
    """ψ alone, for line searches; ``both=True`` returns (ψ_μ, ψ) (they differ for S-ARAP with μ > 0)."""
    check_energy(energy)
    S = np.stack(np.broadcast_arrays(*(np.asarray(s, dtype=float) for s in (s1, s2, s3))), axis=-1).reshape(-1, 3)
    smooth, exact = _psi_sigma(energy, S, mu)[:2]
    return (smooth, exact) if both else smooth


def density(J, energy, mu=0.0, both=False):
    """ψ(J_t) (m,) per tetrahedron for J (m,3,3); +inf on inverted ones for the barrier energies.

    ``both=True`` returns (ψ_μ, ψ): the μ-smoothed S-ARAP and the energy itself, from one SVD.
    """
    check_energy(energy)
    S = signed_svd(J)[1]
    return psi_value(energy, *S.T, mu=mu, both=both)


def gradient(J, energy, mu=0.0):
    """ψ and ∂ψ/∂J = U diag(ψ₁, ψ₂, ψ₃) Vᵀ per tetrahedron: (psi (m,), dpsi (m,3,3)); dpsi meaningful where ψ < ∞."""
    check_energy(energy)
    U, S, V = signed_svd(J)
    psi, _, d1, _ = _psi_sigma(energy, S, mu)
    return psi, np.matmul(U * d1[:, None, :], np.swapaxes(V, 1, 2))


def kink_radius(S):
    """Slope r and branch curvature κ of S-ARAP across each of its two kink sets, for tetrahedra near them.

    Near σᵢ = σⱼ = s (the pair (i, j) of :data:`KINK_PAIRS`, the third singular value apart), ψ is a cone in the
    pair's anti-conformal part a: its coordinates on the unit modes U(Eᵢᵢ − Eⱼⱼ)Vᵀ/√2 and the pair's flip. Moving by
    a splits the pair into s ± ‖a‖/√2, and ψ grows like ψ(kink) + r‖a‖ + κ‖a‖²/2 along a ray, with the one-sided
    derivatives of the ordered formula (module docstring), r = (ψᵢ − ψⱼ)/√2 and κ = (ψᵢᵢ + ψⱼⱼ)/2 on its branch:

        r = (s − 1)(1 − s⁻³)/√2 ≥ 0 on both sets (the term ¼|w(σᵢ) − w(σⱼ)|: half the 2D slope, whose cone is ½|…|),
        κ = 3/2 + 3/2 s⁻⁴ − s⁻³ ≥ 47/32 on σ₁ = σ₂,    κ = 1/2 + 9/2 s⁻⁴ − 3 s⁻³ ≥ 13/32 on σ₂ = σ₃.

    The subdifferential of one cone is the disk ‖F‖ ≤ r. Where σ₁ = σ₂ = σ₃ all three pairs meet and ψ is
    ψ(sR) + ½ w'(s) (λ_max − λ_min) of the symmetric traceless perturbation (5 anti-conformal modes; w' = 2√2 r):
    its subdifferential is {F : ½‖F‖_* ≤ ½ w'(s)} with ‖·‖_* the nuclear norm of the traceless symmetric part, not
    a disk per set.

    Parameters
    ----------
    S : (m,3) numpy array
        Singular values σ₁ ≥ σ₂ ≥ σ₃ > 0; s is the mean of the pair.

    Returns
    -------
    r : (m,2) numpy array
        Columns: the sets σ₁ = σ₂ and σ₂ = σ₃.
    kappa : (m,2) numpy array
    """
    S = np.asarray(S, dtype=float)
    s = np.stack([(S[:, 0] + S[:, 1]) / 2, (S[:, 1] + S[:, 2]) / 2], axis=-1)
    r = (s - 1) * (1 - s**-3) / _R2
    kappa = np.stack([1.5 + 1.5 * s[:, 0] ** -4 - s[:, 0] ** -3, 0.5 + 4.5 * s[:, 1] ** -4 - 3 * s[:, 1] ** -3], -1)
    return r, kappa


def on_kink(S, kink):
    """Which tetrahedra count as sitting on each of S-ARAP's kink sets (the rule of :func:`eigensystem`).

    As in 2D (:func:`defop.variational.energies.on_kink`), per set: the pair's gap is within ``kink`` of it,
    σᵢ − σⱼ ≤ kink · σᵢ, and the cone dominates there, κ (σᵢ − σⱼ)/√2 < r (:func:`kink_radius`).

    Parameters
    ----------
    S : (m,3) numpy array
        σ₁ ≥ σ₂ ≥ |σ₃|.
    kink : float, (m,) or (m,2) numpy array
        One threshold, one per tetrahedron, or one per tetrahedron and set.

    Returns
    -------
    on : (m,2) bool numpy array
        Columns: σ₁ = σ₂ and σ₂ = σ₃.
    """
    S = np.asarray(S, dtype=float)
    kink = np.asarray(kink, dtype=float)
    kink = kink[:, None] if kink.ndim == 1 else kink
    ok, T = _positive(S)
    gap = np.stack([T[:, 0] - T[:, 1], T[:, 1] - T[:, 2]], axis=-1)
    r, kappa = kink_radius(T)
    return ok[:, None] & (gap <= kink * T[:, :2]) & (kappa * gap / _R2 < r)


#: orthonormal σ-space bases (columns) for tetrahedra held on a kink: the free directions first, then the stiff
#: (anti-conformal) ones; held on σ₁ = σ₂, on σ₂ = σ₃, and on both
_HOLD_BASES = (
    np.array([[1, 1, 0], [0, 0, _R2], [1, -1, 0]]).T / _R2,
    np.array([[_R2, 0, 0], [0, 1, 1], [0, 1, -1]]).T / _R2,
    np.stack([np.ones(3) / np.sqrt(3), np.array([1, -1, 0]) / _R2, np.array([1, 1, -2]) / np.sqrt(6)], axis=1),
)


_DIAG = [0, 4, 8]  # vec indices of the diagonal of a 3×3 matrix


def kink_stiff_modes(on):
    """Which of the 9 modes of :func:`eigensystem` are held stiff, for tetrahedra with ``on = on_kink(S, kink)``.

    Held on one set: scaling mode 2 (U(Eᵢᵢ − Eⱼⱼ)Vᵀ/√2) and that pair's flip (6 for σ₁ = σ₂, 8 for σ₂ = σ₃). Held on
    both (σ₁ = σ₂ = σ₃): scaling modes 1 and 2 and all three flips, the five anti-conformal modes.

    Returns
    -------
    stiff : (m,9) bool numpy array
    """
    on = np.asarray(on, dtype=bool)
    a, b = on[:, 0], on[:, 1]
    both, one = a & b, a ^ b
    z = np.zeros_like(a)
    return np.stack([z, both, one | both, z, z, z, a, both, b], axis=-1)


def kink_force(on, F):
    """The size of the force on the held modes, in the norm whose bound is the cone: equilibrium ⇔ ‖F‖ ≤ vol · r.

    Held on one set (σᵢ = σⱼ), the cone ¼|w(σᵢ) − w(σⱼ)| has the disk of radius r (:func:`kink_radius`) as its
    subdifferential, and this is the Euclidean norm of F on the set's two stiff modes (:func:`kink_stiff_modes`).
    Held on both (σ₁ = σ₂ = σ₃ = s), the five stiff modes make a traceless symmetric G = Σₖ Fₖ Aₖ (Aₖ their unit
    matrices in the frame of σ), the cone is ½ w'(s)(λ_max − λ_min) = √2 r (λ_max − λ_min), whose dual norm is
    ½‖G‖_* (half the nuclear norm, the sum of G's positive eigenvalues): returned divided by √2, so the same test
    against r holds.

    Parameters
    ----------
    on : (m,2) bool numpy array
        :func:`on_kink`.
    F : (m,9) numpy array
        Force on each mode of :func:`eigensystem` (held basis); only the stiff modes are read.

    Returns
    -------
    norm : (m,) numpy array
        0 where the tetrahedron is not held.
    """
    on, F = np.asarray(on, dtype=bool), np.asarray(F, dtype=float)
    stiff = kink_stiff_modes(on)
    norm = np.sqrt(np.where(stiff, F * F, 0.0).sum(axis=1))
    both = on[:, 0] & on[:, 1]
    if both.any():
        basis = _HOLD_BASES[2]  # scaling columns 1 and 2 are the traceless diagonals
        Fb = F[both]
        G = (Fb[:, 1:3] @ basis[:, 1:3].T)[:, :, None] * np.eye(3)
        for k, (i, j) in enumerate(PAIRS):
            G[:, i, j] += Fb[:, 6 + k] / _R2
            G[:, j, i] += Fb[:, 6 + k] / _R2
        ev = np.linalg.eigvalsh(G)
        norm[both] = np.maximum(ev, 0.0).sum(axis=1) / _R2
    return norm


def kink_cone(S, on):
    """Slope r and curvature κ of the cone of each held tetrahedron, for :func:`kink_force`'s test ‖F‖ ≤ vol · r.

    Held on one set: that set's (r, κ) of :func:`kink_radius`. Held on both (σ₁ = σ₂ = σ₃): the mean r of the two
    sets (equal at the triple point) and the smaller κ (the larger gain bound (‖F‖ − vol r)² / (2 vol κ)).

    Parameters
    ----------
    S : (m,3) numpy array
    on : (m,2) bool numpy array
        :func:`on_kink`.

    Returns
    -------
    r, kappa : (m,) numpy arrays
    """
    r, kappa = kink_radius(S)
    a, b = np.asarray(on[:, 0], dtype=bool), np.asarray(on[:, 1], dtype=bool)
    pick = np.where(a & ~b, 0, 1)[:, None]
    r1, k1 = np.take_along_axis(r, pick, 1)[:, 0], np.take_along_axis(kappa, pick, 1)[:, 0]
    return np.where(a & b, r.mean(axis=1), r1), np.where(a & b, kappa.min(axis=1), k1)


def kink_offset(S, on):
    """The offset a of held tetrahedra from their kink set on the stiff modes, and its cone cost φ(a).

    Held on σᵢ = σⱼ: a = (σᵢ − σⱼ)/√2 on scaling mode 2 (U(Eᵢᵢ − Eⱼⱼ)Vᵀ/√2), φ = r a + κ a²/2 (:func:`kink_cone`).
    Held on both: a = ((σ₁ − σ₂)/√2, (σ₁ + σ₂ − 2σ₃)/√6) on scaling modes 1 and 2 (the held basis of
    :func:`eigensystem`), φ = √2 r (σ₁ − σ₃) + κ‖a‖²/2 with the larger κ of the two sets: the cone
    √2 r (λ_max − λ_min) of :func:`kink_force`'s dual norm, its curvature bounded from above.

    Parameters
    ----------
    S : (m,3) numpy array
        σ₁ ≥ σ₂ ≥ σ₃ > 0.
    on : (m,2) bool numpy array

    Returns
    -------
    a : (m,9) numpy array
        Coordinates on the modes of :func:`eigensystem` (zero on the soft modes).
    phi : (m,) numpy array
    """
    S = np.asarray(S, dtype=float)
    on = np.asarray(on, dtype=bool)
    both = on[:, 0] & on[:, 1]
    r, kappa = kink_cone(S, on)
    one = np.where(on[:, 0], S[:, 0] - S[:, 1], S[:, 1] - S[:, 2]) / _R2
    a = np.zeros((len(S), 9))
    a[:, 1] = np.where(both, (S[:, 0] - S[:, 1]) / _R2, 0.0)
    a[:, 2] = np.where(both, (S[:, 0] + S[:, 1] - 2 * S[:, 2]) / np.sqrt(6.0), one)
    k_hi = kink_radius(S)[1].max(axis=1)
    n2 = a[:, 1] ** 2 + a[:, 2] ** 2
    phi = np.where(both, _R2 * r * (S[:, 0] - S[:, 2]) + k_hi * n2 / 2, r * one + kappa * one * one / 2)
    return a, np.where(on.any(axis=1), phi, 0.0)


def _hold(on, d1, d2, flip):
    """The kink treatment of :func:`eigensystem` on the held rows: (∂ψ, scaling λ (k,3), eigenvectors (k,3,3), flip)."""
    a, b = on[:, 0], on[:, 1]
    Q = np.where((a & b)[:, None, None], _HOLD_BASES[2], np.where(a[:, None, None], _HOLD_BASES[0], _HOLD_BASES[1]))
    nfree = np.where(a & b, 1, 2)
    free = np.arange(3)[None, :] < nfree[:, None]
    d1 = np.einsum("mij,mj->mi", Q, np.einsum("mji,mj->mi", Q, d1) * free)  # the symmetric subgradient
    M = np.einsum("mji,mjk,mkl->mil", Q, d2, Q)
    big = 1e8 * (1 + np.abs(d2).max(axis=(1, 2)))
    mean, half, off = (M[:, 0, 0] + M[:, 1, 1]) / 2, (M[:, 0, 0] - M[:, 1, 1]) / 2, M[:, 0, 1]
    rad, ang = np.hypot(half, off), 0.5 * np.arctan2(2 * off, 2 * half)
    c, s = np.where(a & b, 1.0, np.cos(ang)), np.where(a & b, 0.0, np.sin(ang))
    R = np.zeros_like(Q)
    R[:, 0, 0], R[:, 1, 0], R[:, 0, 1], R[:, 1, 1], R[:, 2, 2] = c, s, -s, c, 1.0
    lam = np.stack([np.where(a & b, M[:, 0, 0], mean + rad), np.where(a & b, big, mean - rad), big], axis=-1)
    flip = np.where(kink_stiff_modes(on)[:, 6:], big[:, None], flip)
    return d1, lam, np.matmul(Q, R), flip


def eigensystem(J, energy, project=True, mu=0.0, kink=0.0):
    """ψ, ∂ψ/∂J and the analytic eigensystem of the Hessian ∂²ψ/∂vec(J)² per tetrahedron (Smith et al. 2019).

    Modes, orthonormal in vec(J): 0–2 scaling U diag(eₖ) Vᵀ (eₖ the eigenvectors of the 3×3 Hessian of ψ in σ),
    3–5 twists and 6–8 flips of the pairs (σ₁, σ₂), (σ₁, σ₃), (σ₂, σ₃) (module docstring).

    J (m,3,3); ``project`` clamps negative eigenvalues to zero (PSD), else the Hessian is exact where ψ is smooth;
    ``mu`` is S-ARAP's smoothing. ``kink`` (float, (m,) or (m,2)):
        S-ARAP with ``mu = 0`` only: tetrahedra within ``kink`` of a kink set (:func:`on_kink`) are held there, as in
        2D: the gradient keeps only the part symmetric in the pair (the mean of ψᵢ and ψⱼ), and the set's
        anti-conformal modes (:func:`kink_stiff_modes`) get a curvature 1e8 times the scale of ψ's Hessian. Then the
        scaling modes are the held basis: free directions first (their 2×2 or 1×1 Hessian diagonalised), the stiff
        U(Eᵢᵢ − Eⱼⱼ)Vᵀ/√2 last (both sets: U diag(1, 1, 1)Vᵀ/√3, then U diag(1, −1, 0)Vᵀ/√2, U diag(1, 1, −2)Vᵀ/√6).

    Returns
    -------
    (psi (m,), grad (m,9) = vec(∂ψ/∂J), lam (m,9) eigenvalues with non-finite ones set to 0, modes (m,9,9) whose
    column ``modes[t, :, k]`` is vec of the k-th unit eigenmatrix), as :func:`defop.variational.energies.eigensystem`.
    """
    check_energy(energy)
    U, S, V = signed_svd(J)
    psi, d1, d2, twist, flip = psi_derivatives(energy, *S.T, mu=mu)
    d2 = np.where(np.isfinite(d2), d2, 0.0)
    lam_s, E = np.linalg.eigh(d2)
    if energy == "sarap" and mu == 0 and np.any(np.asarray(kink) > 0):
        on = on_kink(S, kink)
        held = on.any(axis=1)
        if held.any():
            d1, lam_s, E, flip = (x.copy() for x in (d1, lam_s, E, flip))
            d1[held], lam_s[held], E[held], flip[held] = _hold(on[held], d1[held], d2[held], flip[held])
    m = len(S)
    K = (U[:, :, None, :, None] * V[:, None, :, None, :]).reshape(m, 9, 9)  # U ⊗ V: vec(U A Vᵀ) = K vec(A)
    Kd = K[:, :, _DIAG]  # vec(U e_a e_aᵀ Vᵀ)
    with np.errstate(invalid="ignore"):  # ∂ψ = inf where ψ overflows (isometric_exp): meaningless there, like ψ
        grad = np.matmul(Kd, d1[:, :, None])[:, :, 0]
    modes = np.empty((m, 9, 9))
    modes[:, :, :3] = np.matmul(Kd, E)
    for k, (i, j) in enumerate(PAIRS):
        modes[:, :, 3 + k] = (K[:, :, 3 * j + i] - K[:, :, 3 * i + j]) / _R2  # twist U(E_ji − E_ij)Vᵀ/√2
        modes[:, :, 6 + k] = (K[:, :, 3 * i + j] + K[:, :, 3 * j + i]) / _R2  # flip U(E_ij + E_ji)Vᵀ/√2
    lam = np.concatenate([lam_s, np.where(np.isfinite(twist), twist, -np.inf), flip], axis=1)
    if project:
        lam = np.maximum(lam, 0.0)
    lam = np.where(np.isfinite(lam), lam, 0.0)
    return psi, grad, lam, modes


def hessian(J, energy, project=True, mu=0.0):
    """ψ, ∂ψ/∂J (m,3,3) and the (projected) Hessian ∂²ψ/∂vec(J)² (m,9,9), assembled from :func:`eigensystem`."""
    psi, grad, lam, modes = eigensystem(J, energy, project, mu)
    H = np.matmul(modes * lam[:, None, :], np.swapaxes(modes, 1, 2))
    return psi, grad.reshape(-1, 3, 3), H
