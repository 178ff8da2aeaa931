"""S-ARAP's smoothed maximum ψ_μ = (f+g)/2 + √(((f−g)/2)² + μ²) − μ: the arithmetic its two implementations share.

Eq. (11) is max(f, g) of its two orderings f, g (:func:`defop.variational.planar.psi_sarap_smooth`). The numpy path
(:mod:`defop.variational.planar`, on arrays) and the fused kernel (:mod:`defop.variational.fused_planar`, one triangle
at a time, these functions compiled by numba) call the same functions: + − × ÷ only, so both give the same bits.
"""

from __future__ import annotations


def half_sums(f, g, f1, f2, g1, g2, f11, f22, g11, g22):
    """(a, b, a1, a2, b1, b2, a11, a22, b11, b22): the half sums a = (f+g)/2 and half differences b = (f−g)/2 of the
    two orderings and of their derivatives in (Σ, σ)."""
    a, b = (f + g) / 2, (f - g) / 2
    a1, a2, b1, b2 = (f1 + g1) / 2, (f2 + g2) / 2, (f1 - g1) / 2, (f2 - g2) / 2
    a11, a22, b11, b22 = (f11 + g11) / 2, (f22 + g22) / 2, (f11 - g11) / 2, (f22 - g22) / 2
    return a, b, a1, a2, b1, b2, a11, a22, b11, b22


def derivatives(t1, t2, a1, a2, b1, b2, a11, a22, b11, b22, w, c):
    """(ψ1, ψ2, ψ11, ψ22, ψ12, twist) of ψ_μ at (Σ, σ) = (t1, t2), from :func:`half_sums` and w = b/r, c = μ²/r³
    (r = √(b² + μ²)); twist = (ψ1 + ψ2)/(Σ + σ), the twist mode's eigenvalue."""
    p1, p2 = a1 + w * b1, a2 + w * b2
    p11 = a11 + w * b11 + c * b1 * b1
    p22 = a22 + w * b22 + c * b2 * b2
    p12 = c * b1 * b2
    return p1, p2, p11, p22, p12, (p1 + p2) / (t1 + t2)
