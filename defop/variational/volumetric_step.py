"""The longest flip-free step along a search direction on tetrahedra: det(J + t dJ) > 0 (Smith & Schaefer 2015)."""

from __future__ import annotations

import numpy as np

from .volumetric_svd import check_jacobians

#: :func:`max_flip_free_step` solves only the tetrahedra whose det(J + t dJ) may fall below this share of det J
#: before the step cap (+inf: all of them)
STEP_SCREEN = 0.5


def _cofactor(A):
    """Cofactor matrices (m,3,3): rows A₁×A₂, A₂×A₀, A₀×A₁ (so det A = A₀·cof(A)₀)."""
    return np.stack([np.cross(A[:, 1], A[:, 2]), np.cross(A[:, 2], A[:, 0]), np.cross(A[:, 0], A[:, 1])], axis=1)


def max_flip_free_step(J, dJ, safety=0.9):
    """Largest t in (0, 1] such that det(J + s·dJ) > 0 for all s in [0, t) (Smith & Schaefer 2015), in 3D.

    Per tetrahedron det(J + t dJ) = c₀ + c₁t + c₂t² + c₃t³ with c₀ = det J, c₁ = cof(J):dJ, c₂ = cof(dJ):J,
    c₃ = det dJ. Its roots are found as s = 1/t, the eigenvalues of the companion matrix of
    s³ + (c₁/c₀)s² + (c₂/c₀)s + c₃/c₀, whose leading coefficient c₀ > 0 never vanishes: the lower-degree cases
    (c₃ = 0, …) are roots s = 0, t = ∞, with no special case. The largest real s > 0 (imaginary part below 1e-4 of
    it: a near-double root counts, conservatively) is polished by two Newton steps on the cubic in t. The step is
    ``safety`` times the smallest root over all tetrahedra, capped at 1. Only the tetrahedra whose cubic may fall below
    :data:`STEP_SCREEN` · c₀ before t = 1/safety are solved: the others cannot shorten the step.

    J (all det > 0) and dJ, its change along the search direction, are (m,3,3); returns t (float).
    """
    J, dJ = check_jacobians(J), check_jacobians(dJ)
    if dJ.shape != J.shape:
        raise ValueError(f"dJ must have the shape of J {J.shape}, got {dJ.shape}")
    cJ, cD = _cofactor(J), _cofactor(dJ)
    c0 = np.einsum("mij,mij->m", cJ, J) / 3
    if np.any(c0 <= 0):
        raise ValueError(f"J must have det J > 0 for every element, got min det {c0.min():.3g}")
    c1, c2 = np.einsum("mij,mij->m", cJ, dJ), np.einsum("mij,mij->m", cD, J)
    c3 = np.einsum("mij,mij->m", cD, dJ) / 3
    # only a root t < 1/safety can shorten the step: skip the tetrahedra whose cubic stays above c₀/2 on
    # [0, 1/safety] by the bound c₀ + Σₖ min(cₖ, 0) Tᵏ (no root there, nor a near-double pair: no flip)
    T = 1 / safety if safety > 0 else np.inf
    with np.errstate(invalid="ignore", over="ignore"):
        low = c0 + np.minimum(c1, 0) * T + np.minimum(c2, 0) * T**2 + np.minimum(c3, 0) * T**3
    near = ~(low > STEP_SCREEN * c0)
    c0, c1, c2, c3 = c0[near], c1[near], c2[near], c3[near]
    C = np.zeros((len(c0), 3, 3))
    C[:, 0, 0], C[:, 0, 1], C[:, 0, 2] = -c1 / c0, -c2 / c0, -c3 / c0
    C[:, 1, 0] = C[:, 2, 1] = 1.0
    s = np.linalg.eigvals(C)
    real = (np.abs(s.imag) <= 1e-4 * np.abs(s)) & (s.real > 0)
    smax = np.where(real, s.real, 0.0).max(axis=1) if len(c0) else np.zeros(0)
    cand = smax > 0
    if not cand.any():
        return 1.0
    t = 1 / smax[cand]
    p = np.stack([c0, c1, c2, c3])[:, cand]
    for _ in range(2):
        f = p[0] + t * (p[1] + t * (p[2] + t * p[3]))
        df = p[1] + t * (2 * p[2] + 3 * t * p[3])
        with np.errstate(divide="ignore", invalid="ignore"):
            tn = t - f / df
        t = np.where(np.isfinite(tn) & (tn > 0) & (np.abs(tn - t) < 0.1 * t), tn, t)
    return min(1.0, safety * float(t.min()))
