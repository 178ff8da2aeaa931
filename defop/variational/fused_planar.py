"""The fused numba kernels of one triangle: the 2×2 closed forms of :mod:`defop.variational.planar` per element.

The signed SVD without trigonometry, Eqs. 10 and 11, the smoothed S-ARAP ψ_μ, the analytic eigensystem of Smith,
de Goes & Kim 2019 and the kink hold of the μ = 0 stage, written per element in the numpy path's order so that
both agree to round-off (``tests/test_fused_kernel.py``); the loops over elements are in
:mod:`defop.variational.fused`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from . import smoothed_max
from .fused_common import JIT, R2, finite

#: the arithmetic S-ARAP's smoothed maximum shares with the numpy path, compiled
_half_sums = njit(**JIT)(smoothed_max.half_sums)
_derivatives = njit(**JIT)(smoothed_max.derivatives)


@njit(**JIT)
def jacobian2(X, F, D, order, t, J):
    """The Jacobian of triangle t into J (2, 2), in :func:`defop.variational.fused.vertex_order`: the general
    kernel (``fused._jacobian``) unrolled, the same sums in the same order."""
    i0, i1, i2 = order[t, 0], order[t, 1], order[t, 2]
    v0, v1, v2 = F[t, i0], F[t, i1], F[t, i2]
    for a in range(2):
        x0, x1, x2 = X[v0, a], X[v1, a], X[v2, a]
        for b in range(2):
            v = 0.0
            v += x0 * D[t, i0, b]
            v += x1 * D[t, i1, b]
            v += x2 * D[t, i2, b]
            J[a, b] = v


@njit(**JIT)
def sigma2(J):
    """The signed singular values (Σ, σ) of a 2×2 J alone (:func:`_frame2` without the frame)."""
    a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    Qn, Rn = math.hypot((a + d) / 2, (c - b) / 2), math.hypot((a - d) / 2, (c + b) / 2)
    return Qn + Rn, Qn - Rn


@njit(**JIT)
def _hypot(x, y):
    """√(x² + y²) for the eigenvalues of ψ's σ-Hessian (libm's hypot guards against overflow at several times the
    cost; the singular values keep it, whose difference Qn − Rn cancels near a flip)."""
    return math.sqrt(x * x + y * y)


@njit(**JIT)
def _frame2(J):
    """Signed singular values and frame of a 2×2 J (:func:`defop.variational.planar.svd_frame`)."""
    a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    Qn, Rn = math.hypot(E, H), math.hypot(F, G)  # as numpy: σ = Qn − Rn cancels near a flip
    ca, sa = (E / Qn, H / Qn) if Qn > 0 else (1.0, 0.0)
    cb, sb = (F / Rn, G / Rn) if Rn > 0 else (1.0, 0.0)
    return Qn + Rn, Qn - Rn, ca, sa, cb, sb


@njit(**JIT)
def _cube(x):
    return x * x * x


@njit(**JIT)
def _sarap_smooth(t1, t2, ok, mu):
    """:func:`defop.variational.planar.psi_sarap_smooth` for one element."""
    f = (t1 - 1) ** 2 + (1 / t2 - 1) ** 2
    g = (t2 - 1) ** 2 + (1 / t1 - 1) ** 2
    f1, f2 = 2 * (t1 - 1), 2 * (t2 - 1) / _cube(t2)
    g1, g2 = 2 * (t1 - 1) / _cube(t1), 2 * (t2 - 1)
    f11, f22 = 2.0, 6 / (t2 * t2) ** 2 - 4 / _cube(t2)
    g11, g22 = 6 / (t1 * t1) ** 2 - 4 / _cube(t1), 2.0
    a, b, a1, a2, b1, b2, a11, a22, b11, b22 = _half_sums(f, g, f1, f2, g1, g2, f11, f22, g11, g22)
    r = math.sqrt(b * b + mu * mu)
    w, c = b / r, mu * mu / _cube(r)
    psi = a + r - mu if ok else np.inf
    p1, p2, p11, p22, p12, twist = _derivatives(t1, t2, a1, a2, b1, b2, a11, a22, b11, b22, w, c)
    gap = t1 - t2
    flip = (p1 - p2) / gap if gap > 1e-6 * t1 else p11 - p12
    return psi, p1, p2, p11, p22, p12, twist, flip


@njit(**JIT)
def _sarap_exact(t1, t2, ok):
    """Eq. (11)'s derivatives in (Σ, σ), the flip eigenvalue capped across the kink (planar.psi_derivatives)."""
    psi = (t1 - 1) ** 2 + (1 / t2 - 1) ** 2 if ok else np.inf
    p1 = 2 * (t1 - 1)
    p2 = 2 * (t2 - 1) / _cube(t2)
    p11 = 2.0
    p22 = 6 / (t2 * t2) ** 2 - 4 / _cube(t2)
    twist = (p1 + p2) / (t1 + t2)
    gap = t1 - t2
    num = p1 - p2
    cap = 1e4 * (1 + p11 + abs(p22))
    if gap > 1e-8:
        flip = num / gap
    elif abs(num) > 1e-10:
        flip = cap
    else:
        flip = (p11 + p22) / 2
    return psi, p1, p2, p11, p22, 0.0, twist, min(flip, cap)


@njit(**JIT)
def _derivatives2(code, s1, s2, mu):
    """(ψ, ψ1, ψ2, ψ11, ψ22, ψ12, twist, flip) of :func:`defop.variational.planar.psi_derivatives`."""
    if code == 0:
        ssum = s1 + s2
        twist = 2 - 4 / ssum if abs(ssum) > 1e-12 else -np.inf
        psi = (s1 - 1) ** 2 + (s2 - 1) ** 2
        return psi, 2 * (s1 - 1), 2 * (s2 - 1), 2.0, 2.0, 0.0, twist, 2.0
    ok = s2 > 0
    t1, t2 = (s1, s2) if ok else (1.0, 1.0)
    if code == 1:
        return _sarap_smooth(t1, t2, ok, mu) if mu > 0 else _sarap_exact(t1, t2, ok)
    psi = t1**2 + t2**2 + 1 / (t1 * t1) + 1 / (t2 * t2) if ok else np.inf
    den = _cube(t1 * t2)
    twist = 2 - 2 * (t1**2 - t1 * t2 + t2**2) / den
    flip = 2 + 2 * (t1**2 + t1 * t2 + t2**2) / den
    p1, p2 = 2 * t1 - 2 / _cube(t1), 2 * t2 - 2 / _cube(t2)
    return psi, p1, p2, 2 + 6 / (t1 * t1) ** 2, 2 + 6 / (t2 * t2) ** 2, 0.0, twist, flip


@njit(**JIT)
def _on_kink2(s1, s2, kink):
    """:func:`defop.variational.planar.on_kink` for one element."""
    if not s2 > 0:
        return False
    s = (s1 + s2) / 2
    r = math.sqrt(2.0) * (s - 1) * (1 - (1 / _cube(s)))
    kappa = 1 + 3 * (1 / (s * s) ** 2) - 2 * (1 / _cube(s))
    gap = s1 - s2
    return gap <= kink * s1 and kappa * gap / math.sqrt(2.0) < r


@njit(**JIT)
def _half_angle(y, x):
    """(cos θ/2, sin θ/2) of θ = atan2(y, x) without trigonometry; exact where the scaling modes are already diagonal
    (y = 0, x > 0), and within a few ulps of ``planar.eigensystem``'s cos, sin of atan2(y, x)/2 elsewhere."""
    if y == 0.0 and x > 0.0:
        return 1.0, 0.0
    R = _hypot(x, y)
    if R == 0.0:
        return 1.0, 0.0
    if x >= 0.0:  # the half-angle formulas, each where it is well conditioned
        c = math.sqrt((1 + x / R) / 2)
        return c, y / (2 * R * c)
    s = math.copysign(math.sqrt((1 - x / R) / 2), y)
    return y / (2 * R * s), s


@njit(**JIT)
def eigen2(J, code, mu, kink, hold, project, grad, lam, modes):
    """ψ; vec ∂ψ/∂J into grad (4,), eigenvalues into lam (4,), unit eigenvectors into the columns of modes (4, 4).

    :func:`defop.variational.planar.eigensystem` for one triangle; ``hold``: S-ARAP at μ = 0 with some positive
    kink threshold (the elements within ``kink`` of Eq. 11's kink are held there).
    """
    s1, s2, ca, sa, cb, sb = _frame2(J)
    psi, p1, p2, p11, p22, p12, twist, flip = _derivatives2(code, s1, s2, mu)
    r = R2
    rot = (ca * r, -sa * r, sa * r, ca * r)
    ref = (cb * r, sb * r, sb * r, -cb * r)
    tw = (-sa * r, -ca * r, ca * r, -sa * r)
    fl = (-sb * r, cb * r, cb * r, sb * r)
    u, v = (p1 + p2) * r, (p1 - p2) * r
    p11, p22, p12 = finite(p11), finite(p22), finite(p12)
    mean, half = (p11 + p22) / 2, (p11 - p22) / 2
    rad = _hypot(half, p12)
    c, s = _half_angle(2 * p12, p11 - p22)
    x1, y1, x2, y2 = (c + s) * r, (c - s) * r, (c - s) * r, -(c + s) * r
    lam[0], lam[1], lam[2], lam[3] = mean + rad, mean - rad, twist if np.isfinite(twist) else -np.inf, flip
    if hold and _on_kink2(s1, s2, kink):
        big = 1e8 * (1 + abs(p11) + abs(p22))
        v = 0.0
        lam[0], lam[1], lam[3] = (p11 + p22) / 2, big, big
        x1, y1, x2, y2 = 1.0, 0.0, 0.0, 1.0
    for q in range(4):
        grad[q] = u * rot[q] + v * ref[q]
        modes[q, 0] = x1 * rot[q] + y1 * ref[q]
        modes[q, 1] = x2 * rot[q] + y2 * ref[q]
        modes[q, 2] = tw[q]
        modes[q, 3] = fl[q]
    for q in range(4):
        if project:
            lam[q] = max(lam[q], 0.0)
        lam[q] = finite(lam[q])
    return psi


@njit(**JIT)
def value2(code, s1, s2, mu):
    """(ψ_μ, ψ) of :func:`defop.variational.planar.psi_value` (``both=True``) for one triangle."""
    if code == 0:
        psi = (s1 - 1) ** 2 + (s2 - 1) ** 2
        return psi, psi
    if not s2 > 0:
        return np.inf, np.inf
    if code == 1:
        f = (s1 - 1) ** 2 + (1 / s2 - 1) ** 2
        g = (s2 - 1) ** 2 + (1 / s1 - 1) ** 2
        a, b = (f + g) / 2, (f - g) / 2
        exact = a + abs(b)
        return (a + math.sqrt(b * b + mu * mu) - mu if mu > 0 else exact), exact
    psi = s1**2 + s2**2 + 1 / (s1 * s1) + 1 / (s2 * s2)
    return psi, psi


@njit(**JIT)
def local2(D, t, At, grad, modes, g, F, W):
    """Add A_t Bᵀ vec ∂ψ/∂J into g and write W[t] = Bᵀ modes, for triangles (``fused._local`` unrolled)."""
    for i in range(3):
        vi = F[t, i]
        for a in range(2):
            g[2 * vi + a] += At * (D[t, i, 0] * grad[2 * a] + D[t, i, 1] * grad[2 * a + 1])
            for q in range(4):
                W[t, 2 * i + a, q] = D[t, i, 0] * modes[2 * a, q] + D[t, i, 1] * modes[2 * a + 1, q]


@njit(**JIT)
def scatter2(W, lp, slot, t, data):
    """Add the kept entries of W[t] diag(lp) W[t]ᵀ into the CSC values, for triangles (``fused._scatter_one``
    unrolled)."""
    for i in range(6):
        for j in range(6):
            p = slot[t, i, j]
            if p >= 0:
                v = 0.0
                for q in range(4):
                    v += W[t, i, q] * lp[q] * W[t, j, q]
                data[p] += v


@njit(**JIT)
def flip_free_step2(J, dJ, safety):
    """:func:`defop.variational.planar.max_flip_free_step` in one pass: the smallest positive root of
    det(J + t dJ) = c + b t + a t² over the triangles (the same formulas), times ``safety``, capped at 1."""
    t_min = np.inf
    for k in range(J.shape[0]):
        a = dJ[k, 0, 0] * dJ[k, 1, 1] - dJ[k, 0, 1] * dJ[k, 1, 0]
        b = J[k, 0, 0] * dJ[k, 1, 1] + dJ[k, 0, 0] * J[k, 1, 1] - J[k, 0, 1] * dJ[k, 1, 0] - dJ[k, 0, 1] * J[k, 1, 0]
        c = J[k, 0, 0] * J[k, 1, 1] - J[k, 0, 1] * J[k, 1, 0]
        root = np.inf
        if abs(a) <= 1e-14 * (abs(a) + abs(b) + abs(c)):
            if b != 0.0:
                tl = -c / b
                if tl > 0:
                    root = tl
        else:
            disc = b * b - 4 * a * c
            if disc >= 0:
                q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
                for r in (q / a, c / q):
                    if r > 0 and r < root:
                        root = r
        t_min = min(t_min, root)
    return min(1.0, safety * t_min)
