"""Fused numba kernels of one Newton iteration: E, ∇E and the (projected) Hessian's values, straight from X.

The numpy path (:func:`defop.variational.energies.eigensystem`, then ``ReducedProblem.grad_hess`` and
``ReducedHessian.assemble``) builds every per-element array in turn: Jacobians, signed singular values, ψ and its
σ-derivatives, the modes, W = Bᵀ modes, the element Hessians K_t = A_t W diag(λ) Wᵀ, then one ``bincount``. On
meshes of a few thousand elements that is a dozen passes over memory and about 70 numpy calls per iteration, about
three times the qdldl factorisation it feeds. Here one loop over the elements does it all, in registers, and adds
each element's kept upper-triangle entries straight into the CSC values of the fixed pattern (an element → CSC
slot map computed once, :func:`slot_map`). The line search's energies are one more loop (:func:`energies_2d`).

The formulas are those of :mod:`defop.variational.planar` (the 2×2 closed forms: the signed SVD without
trigonometry, Eqs. 10 and 11, the smoothed S-ARAP ψ_μ, the analytic eigensystem of Smith, de Goes & Kim 2019, the
kink hold of the μ = 0 stage) written per element in the same order, so that both paths agree to round-off
(``tests/test_fused_kernel.py``: 1e-12 relative, random and near-flip deformations, held elements). The numpy path
stays the reference and covers what the kernels do not (the isometric_max / isometric_exp energies). The
assembly order of each CSC value is that of the numpy ``bincount`` (elements in order, local entries row-major).

Energy codes: :data:`CODES`. numba (BSD-2) compiles these on first use and caches them beside this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: error_model "numpy": a division by zero gives inf or nan, as in the numpy path (and costs no check)
_JIT = {"cache": True, "nogil": True, "boundscheck": False, "error_model": "numpy"}

#: the energies with a fused kernel, and their codes
CODES = {"arap": 0, "sarap": 1, "isometric": 2}
#: the dimensions with a fused kernel
DIMS = (2, 3)
_R = 1 / math.sqrt(2.0)


def slot_map(keep, inv, m, k):
    """Element → CSC slot map: ``slot[t, i, j]`` is the index into the CSC values of local entry (i, j), else −1.

    Parameters
    ----------
    keep : (q,) int numpy array
        Flat indices t·k² + i·k + j of the kept entries (upper triangle of the free-free block).
    inv : (q,) int numpy array
        Their CSC slots.
    m, k : int
        Elements, local dofs per element ((d + 1)·d).

    Returns
    -------
    slot : (m, k, k) int64 numpy array
    """
    slot = -np.ones(m * k * k, np.int64)
    slot[keep] = inv
    return slot.reshape(m, k, k)


def vertex_order(F):
    """(m, d+1) the local vertices of each element by increasing index: the order in which ``Mesh.jacobians``'
    sparse operator (sorted CSR columns) sums them, so that both paths form bit-identical Jacobians."""
    return np.argsort(F, axis=1, kind="stable")


@njit(**_JIT)
def _jacobian(X, F, D, order, t, d, J):
    """J[a, b] = Σ_i X[F[t, i], a] D[t, i, b] into J (d, d), summed in :func:`vertex_order`."""
    for a in range(d):
        for b in range(d):
            v = 0.0
            for ii in range(d + 1):
                i = order[t, ii]
                v += X[F[t, i], a] * D[t, i, b]
            J[a, b] = v


@njit(**_JIT)
def _jacobian2(X, F, D, order, t, J):
    """:func:`_jacobian` for triangles, unrolled (the same sums in the same order)."""
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


@njit(**_JIT)
def _sigma2(J):
    """The signed singular values (Σ, σ) of a 2×2 J alone (:func:`_frame2` without the frame)."""
    a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    Qn, Rn = math.hypot((a + d) / 2, (c - b) / 2), math.hypot((a - d) / 2, (c + b) / 2)
    return Qn + Rn, Qn - Rn


@njit(**_JIT)
def _hypot(x, y):
    """√(x² + y²) for the eigenvalues of ψ's σ-Hessian (libm's hypot guards against overflow at several times the
    cost; the singular values keep it, whose difference Qn − Rn cancels near a flip)."""
    return math.sqrt(x * x + y * y)


@njit(**_JIT)
def _frame2(J):
    """Signed singular values and frame of a 2×2 J (:func:`defop.variational.planar.svd_frame`)."""
    a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    Qn, Rn = math.hypot(E, H), math.hypot(F, G)  # as numpy: σ = Qn − Rn cancels near a flip
    ca, sa = (E / Qn, H / Qn) if Qn > 0 else (1.0, 0.0)
    cb, sb = (F / Rn, G / Rn) if Rn > 0 else (1.0, 0.0)
    return Qn + Rn, Qn - Rn, ca, sa, cb, sb


@njit(**_JIT)
def _cube(x):
    return x * x * x


@njit(**_JIT)
def _sarap_smooth(t1, t2, ok, mu):
    """:func:`defop.variational.planar.psi_sarap_smooth` for one element."""
    f = (t1 - 1) ** 2 + (1 / t2 - 1) ** 2
    g = (t2 - 1) ** 2 + (1 / t1 - 1) ** 2
    f1, f2 = 2 * (t1 - 1), 2 * (t2 - 1) / _cube(t2)
    g1, g2 = 2 * (t1 - 1) / _cube(t1), 2 * (t2 - 1)
    f11, f22 = 2.0, 6 / (t2 * t2) ** 2 - 4 / _cube(t2)
    g11, g22 = 6 / (t1 * t1) ** 2 - 4 / _cube(t1), 2.0
    a, b = (f + g) / 2, (f - g) / 2
    a1, a2, b1, b2 = (f1 + g1) / 2, (f2 + g2) / 2, (f1 - g1) / 2, (f2 - g2) / 2
    a11, a22, b11, b22 = (f11 + g11) / 2, (f22 + g22) / 2, (f11 - g11) / 2, (f22 - g22) / 2
    r = math.sqrt(b * b + mu * mu)
    w, c = b / r, mu * mu / _cube(r)
    psi = a + r - mu if ok else np.inf
    p1, p2 = a1 + w * b1, a2 + w * b2
    p11 = a11 + w * b11 + c * b1 * b1
    p22 = a22 + w * b22 + c * b2 * b2
    p12 = c * b1 * b2
    twist = (p1 + p2) / (t1 + t2)
    gap = t1 - t2
    flip = (p1 - p2) / gap if gap > 1e-6 * t1 else p11 - p12
    return psi, p1, p2, p11, p22, p12, twist, flip


@njit(**_JIT)
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


@njit(**_JIT)
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


@njit(**_JIT)
def _on_kink2(s1, s2, kink):
    """:func:`defop.variational.planar.on_kink` for one element."""
    if not s2 > 0:
        return False
    s = (s1 + s2) / 2
    r = math.sqrt(2.0) * (s - 1) * (1 - (1 / _cube(s)))
    kappa = 1 + 3 * (1 / (s * s) ** 2) - 2 * (1 / _cube(s))
    gap = s1 - s2
    return gap <= kink * s1 and kappa * gap / math.sqrt(2.0) < r


@njit(**_JIT)
def _finite(x):
    return x if np.isfinite(x) else 0.0


@njit(**_JIT)
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


@njit(**_JIT)
def eigen2(J, code, mu, kink, hold, project, grad, lam, modes):
    """ψ; vec ∂ψ/∂J into grad (4,), eigenvalues into lam (4,), unit eigenvectors into the columns of modes (4, 4).

    :func:`defop.variational.planar.eigensystem` for one triangle; ``hold``: S-ARAP at μ = 0 with some positive
    kink threshold (the elements within ``kink`` of Eq. 11's kink are held there).
    """
    s1, s2, ca, sa, cb, sb = _frame2(J)
    psi, p1, p2, p11, p22, p12, twist, flip = _derivatives2(code, s1, s2, mu)
    r = _R
    rot = (ca * r, -sa * r, sa * r, ca * r)
    ref = (cb * r, sb * r, sb * r, -cb * r)
    tw = (-sa * r, -ca * r, ca * r, -sa * r)
    fl = (-sb * r, cb * r, cb * r, sb * r)
    u, v = (p1 + p2) * r, (p1 - p2) * r
    p11, p22, p12 = _finite(p11), _finite(p22), _finite(p12)
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
        lam[q] = _finite(lam[q])
    return psi


@njit(**_JIT)
def _value2(code, s1, s2, mu):
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


@njit(**_JIT)
def _local(D, t, d, At, grad, modes, g, F, W):
    """Add A_t Bᵀ vec ∂ψ/∂J into g and write W[t] = Bᵀ modes (the element's local dofs × modes)."""
    nm = d * d
    for i in range(d + 1):
        vi = F[t, i]
        for a in range(d):
            s = 0.0
            for b in range(d):
                s += D[t, i, b] * grad[a * d + b]
            g[d * vi + a] += At * s
            for q in range(nm):
                w = 0.0
                for b in range(d):
                    w += D[t, i, b] * modes[a * d + b, q]
                W[t, d * i + a, q] = w


@njit(**_JIT)
def _local2(D, t, At, grad, modes, g, F, W):
    """:func:`_local` for triangles, with constant loop bounds (unrolled)."""
    for i in range(3):
        vi = F[t, i]
        for a in range(2):
            g[2 * vi + a] += At * (D[t, i, 0] * grad[2 * a] + D[t, i, 1] * grad[2 * a + 1])
            for q in range(4):
                W[t, 2 * i + a, q] = D[t, i, 0] * modes[2 * a, q] + D[t, i, 1] * modes[2 * a + 1, q]


@njit(**_JIT)
def _scatter2(W, lp, slot, t, data):
    """:func:`_scatter_one` for triangles, with constant loop bounds (unrolled)."""
    for i in range(6):
        for j in range(6):
            p = slot[t, i, j]
            if p >= 0:
                v = 0.0
                for q in range(4):
                    v += W[t, i, q] * lp[q] * W[t, j, q]
                data[p] += v


@njit(**_JIT)
def _scatter_one(W, lp, slot, t, data):
    """Add the kept entries of W[t] diag(lp) W[t]ᵀ into the CSC values."""
    k, nm = W.shape[1], W.shape[2]
    for i in range(k):
        for j in range(k):
            p = slot[t, i, j]
            if p >= 0:
                v = 0.0
                for q in range(nm):
                    v += W[t, i, q] * lp[q] * W[t, j, q]
                data[p] += v


@njit(**_JIT)
def scatter(W, lamA, slot, project, data):
    """``ReducedHessian.assemble``: Σ_t W_t diag(λ_t A_t) W_tᵀ (λ clamped at 0 when ``project``) into data (nnz,)."""
    nm = W.shape[2]
    lp = np.empty(nm)
    data[:] = 0.0
    for t in range(W.shape[0]):
        for q in range(nm):
            lp[q] = max(lamA[t, q], 0.0) if project else lamA[t, q]
        _scatter_one(W, lp, slot, t, data)


# ------------------------------------------------------------------------------------------------------ 3D
_PAIRS = ((0, 1), (0, 2), (1, 2))
_R3 = 1 / math.sqrt(3.0)
_R6 = 1 / math.sqrt(6.0)


@njit(**_JIT)
def _w3(t):
    """w = u − v = (t − 1)² − (1/t − 1)² and its first two derivatives."""
    it3 = 1 / (t * t * t)
    return (t - 1) ** 2 - (1 / t - 1) ** 2, 2 * (t - 1) * (1 - it3), 2 - 6 * it3 / t + 4 * it3


@njit(**_JIT)
def _sarap3(T, mu, d1, d2):
    """:func:`defop.variational.volumetric._sarap` for one tetrahedron: (ψ_μ, ψ); ∂ψ_μ into d1 (3,), ∂²ψ_μ into d2."""
    base = 0.0
    for i in range(3):
        t = T[i]
        it3 = 1 / (t * t * t)
        base += (t - 1) ** 2 + (1 / t - 1) ** 2
        d1[i] = (t - 1) * (1 + it3)
        for j in range(3):
            d2[i, j] = 0.0
        d2[i, i] = 1 + 3 * it3 / t - 2 * it3
    exact = smooth = 0.5 * base
    for i, j in _PAIRS:
        wi, w1i, w2i = _w3(T[i])
        wj, w1j, w2j = _w3(T[j])
        x = wi - wj
        exact += 0.25 * abs(x)
        if mu > 0:
            r = math.sqrt(x * x / 4 + mu * mu)
            h, h1, h2 = r - mu, x / (4 * r), mu * mu / (4 * r * r * r)
        else:
            h, h1, h2 = abs(x) / 2, np.sign(x) / 2, 0.0
        smooth += 0.5 * h
        d1[i] += 0.5 * h1 * w1i
        d1[j] -= 0.5 * h1 * w1j
        d2[i, i] += 0.5 * (h2 * w1i**2 + h1 * w2i)
        d2[j, j] += 0.5 * (h2 * w1j**2 - h1 * w2j)
        d2[i, j] -= 0.5 * h2 * w1i * w1j
        d2[j, i] = d2[i, j]
    return smooth, exact


@njit(**_JIT)
def _sigma3(code, S, mu, T, d1, d2):
    """(ψ_μ, ψ) of :func:`defop.variational.volumetric._psi_sigma`; T (3,) gets the σ the derivatives are taken at
    (ones off the barriers' domain), d1 (3,) and d2 (3, 3) the derivatives."""
    for i in range(3):
        T[i] = S[i]
    if code == 0:
        psi = 0.0
        for i in range(3):
            psi += (S[i] - 1) ** 2
            d1[i] = 2 * (S[i] - 1)
            for j in range(3):
                d2[i, j] = 2.0 if i == j else 0.0
        return psi, psi
    ok = S[2] > 0
    if not ok:
        T[0] = T[1] = T[2] = 1.0
    if code == 1:
        smooth, exact = _sarap3(T, mu, d1, d2)
    else:
        smooth = 0.0
        for i in range(3):
            t = T[i]
            smooth += t * t + 1 / (t * t)
            d1[i] = 2 * t - 2 / (t * t * t)
            for j in range(3):
                d2[i, j] = 2 + 6 / (t * t) ** 2 if i == j else 0.0
        exact = smooth
    return (smooth, exact) if ok else (np.inf, np.inf)


@njit(**_JIT)
def _twist_flip3(code, T, d1, d2, mu, twist, flip):
    """:func:`defop.variational.volumetric._twist_flip` for one tetrahedron, into twist (3,) and flip (3,)."""
    for k in range(3):
        i, j = _PAIRS[k]
        ssum, gap, num = T[i] + T[j], T[i] - T[j], d1[i] - d1[j]
        twist[k] = (d1[i] + d1[j]) / ssum if abs(ssum) > 1e-12 else -np.inf
        if code == 1 and mu == 0:
            pii, pjj = d2[i, i], d2[j, j]
            cap = 1e4 * (1 + pii + abs(pjj))
            lim = cap if abs(num) > 1e-10 else (pii + pjj) / 2
            flip[k] = min(num / gap if gap > 1e-8 else lim, cap)
        else:
            flip[k] = num / gap if gap > 1e-6 * abs(T[i]) else d2[i, i] - d2[i, j]


@njit(**_JIT)
def _eigh3(M, lam, E):
    """Eigenvalues (ascending) of the symmetric 3×3 M into lam and unit eigenvectors into the columns of E (cyclic
    Jacobi; M is overwritten). A diagonal M needs no rotation: its eigenvectors are the unit vectors."""
    for i in range(3):
        for j in range(3):
            E[i, j] = 1.0 if i == j else 0.0
    for _ in range(50):
        off = M[0, 1] ** 2 + M[0, 2] ** 2 + M[1, 2] ** 2
        scale = M[0, 0] ** 2 + M[1, 1] ** 2 + M[2, 2] ** 2
        if not off > 1e-34 * scale:
            break
        for p, q in _PAIRS:
            if M[p, q] == 0.0:
                continue
            theta = (M[q, q] - M[p, p]) / (2 * M[p, q])
            t = math.copysign(1.0, theta) / (abs(theta) + math.sqrt(theta * theta + 1))
            c = 1 / math.sqrt(t * t + 1)
            s = t * c
            for k in range(3):  # M ← Gᵀ M G, E ← E G
                mkp, mkq = M[k, p], M[k, q]
                M[k, p], M[k, q] = c * mkp - s * mkq, s * mkp + c * mkq
            for k in range(3):
                mpk, mqk = M[p, k], M[q, k]
                M[p, k], M[q, k] = c * mpk - s * mqk, s * mpk + c * mqk
            for k in range(3):
                ekp, ekq = E[k, p], E[k, q]
                E[k, p], E[k, q] = c * ekp - s * ekq, s * ekp + c * ekq
    for i in range(3):
        lam[i] = M[i, i]
    for i in range(3):  # selection sort, columns with them
        k = i
        for j in range(i + 1, 3):
            if lam[j] < lam[k]:
                k = j
        if k != i:
            lam[i], lam[k] = lam[k], lam[i]
            for r in range(3):
                E[r, i], E[r, k] = E[r, k], E[r, i]


@njit(**_JIT)
def _on_set3(T, k, kink):
    """:func:`defop.variational.volumetric.on_kink` for one tetrahedron and kink set k (0: σ₁ = σ₂, 1: σ₂ = σ₃),
    T: σ with ones off the barrier's domain."""
    s = (T[k] + T[k + 1]) / 2
    it3 = 1 / (s * s * s)
    r = (s - 1) * (1 - it3) / math.sqrt(2.0)
    kappa = 1.5 + 1.5 * it3 / s - it3 if k == 0 else 0.5 + 4.5 * it3 / s - 3 * it3
    gap = T[k] - T[k + 1]
    return gap <= kink * T[k] and kappa * gap / math.sqrt(2.0) < r


@njit(**_JIT)
def _hold_basis(a, b, Q):
    """The held σ-space basis of :data:`defop.variational.volumetric._HOLD_BASES` (columns) into Q (3, 3)."""
    r2 = _R
    for i in range(3):
        for j in range(3):
            Q[i, j] = 0.0
    if a and b:
        for i in range(3):
            Q[i, 0] = _R3
        Q[0, 1], Q[1, 1] = r2, -r2
        Q[0, 2], Q[1, 2], Q[2, 2] = _R6, _R6, -2 * _R6
    elif a:
        Q[0, 0], Q[1, 0], Q[2, 1], Q[0, 2], Q[1, 2] = r2, r2, 1.0, r2, -r2
    else:
        Q[0, 0], Q[1, 1], Q[2, 1], Q[1, 2], Q[2, 2] = 1.0, r2, r2, r2, -r2


@njit(**_JIT)
def _hold3(a, b, d1, d2, lam, E, flip, Q, M, R, c1):
    """:func:`defop.variational.volumetric._hold` for one held tetrahedron: d1, lam (3,), E (3, 3), flip in place
    (Q, M, R (3, 3) and c1 (3,) scratch)."""
    _hold_basis(a, b, Q)
    both = a and b
    nfree = 1 if both else 2
    c1[:] = 0.0
    R[:] = 0.0
    for j in range(nfree):  # the symmetric subgradient: d1 projected on the free directions
        c1[j] = Q[0, j] * d1[0] + Q[1, j] * d1[1] + Q[2, j] * d1[2]
    big = 0.0
    for i in range(3):
        d1[i] = Q[i, 0] * c1[0] + Q[i, 1] * c1[1] + Q[i, 2] * c1[2]
        for j in range(3):
            big = max(big, abs(d2[i, j]))
            v = 0.0
            for p in range(3):
                for q in range(3):
                    v += Q[p, i] * d2[p, q] * Q[q, j]
            M[i, j] = v
    big = 1e8 * (1 + big)
    mean, half, off = (M[0, 0] + M[1, 1]) / 2, (M[0, 0] - M[1, 1]) / 2, M[0, 1]
    rad = math.hypot(half, off)
    if both:
        c, s = 1.0, 0.0
    else:
        ang = 0.5 * math.atan2(2 * off, 2 * half)
        c, s = math.cos(ang), math.sin(ang)
    R[0, 0], R[1, 0], R[0, 1], R[1, 1], R[2, 2] = c, s, -s, c, 1.0
    lam[0], lam[1], lam[2] = (M[0, 0], big, big) if both else (mean + rad, mean - rad, big)
    if a:
        flip[0] = big
    if both:
        flip[1] = big
    if b:
        flip[2] = big
    for i in range(3):
        for j in range(3):
            E[i, j] = Q[i, 0] * R[0, j] + Q[i, 1] * R[1, j] + Q[i, 2] * R[2, j]


@njit(**_JIT)
def eigen3(U, S, V, code, mu, kink0, kink1, hold, grad, lam, modes, v3, m3):
    """ψ; vec ∂ψ/∂J into grad (9,), eigenvalues into lam (9,), unit eigenvectors into the columns of modes (9, 9).

    :func:`defop.variational.volumetric.eigensystem` for one tetrahedron, from its signed SVD U diag(S) Vᵀ; v3 (6, 3)
    and m3 (5, 3, 3) are scratch."""
    T, d1, twist, flip, ls = v3[0], v3[1], v3[2], v3[3], v3[4]
    d2, E = m3[0], m3[1]
    psi = _sigma3(code, S, mu, T, d1, d2)[0]
    _twist_flip3(code, T, d1, d2, mu, twist, flip)
    for i in range(3):
        for j in range(3):
            d2[i, j] = _finite(d2[i, j])
    a = hold and S[2] > 0 and _on_set3(T, 0, kink0)
    b = hold and S[2] > 0 and _on_set3(T, 1, kink1)
    if a or b:
        _hold3(a, b, d1, d2, ls, E, flip, m3[2], m3[3], m3[4], v3[5])
    else:
        _eigh3(d2, ls, E)
    for r in range(9):
        p, q = r // 3, r % 3
        grad[r] = 0.0
        for c in range(3):
            grad[r] += U[p, c] * V[q, c] * d1[c]
            modes[r, c] = U[p, 0] * V[q, 0] * E[0, c] + U[p, 1] * V[q, 1] * E[1, c] + U[p, 2] * V[q, 2] * E[2, c]
        for k in range(3):
            i, j = _PAIRS[k]
            modes[r, 3 + k] = (U[p, j] * V[q, i] - U[p, i] * V[q, j]) * _R
            modes[r, 6 + k] = (U[p, i] * V[q, j] + U[p, j] * V[q, i]) * _R
    for k in range(3):
        lam[k] = ls[k]
        lam[3 + k] = twist[k] if np.isfinite(twist[k]) else -np.inf
        lam[6 + k] = flip[k]
    for q in range(9):
        lam[q] = _finite(lam[q])
    return psi


@njit(**_JIT)
def _unit_orthogonal(u, out):
    """A unit vector orthogonal to the unit u into out (the cross product with the axis least aligned with u)."""
    k = 0
    for i in range(1, 3):
        if abs(u[i]) < abs(u[k]):
            k = i
    e = np.zeros(3)
    e[k] = 1.0
    out[0], out[1], out[2] = u[1] * e[2] - u[2] * e[1], u[2] * e[0] - u[0] * e[2], u[0] * e[1] - u[1] * e[0]
    n = math.sqrt(out[0] ** 2 + out[1] ** 2 + out[2] ** 2)
    for i in range(3):
        out[i] /= n


@njit(**_JIT)
def svd3(J, U, S, V):
    """Signed SVD J = U diag(S) Vᵀ of a 3×3 J by one-sided Jacobi (Hestenes): U, V rotations, S[0] ≥ S[1] ≥ |S[2]|,
    S[2] < 0 exactly when det J < 0 (:func:`defop.variational.volumetric.signed_svd`, without LAPACK's per-call cost).

    Givens rotations from the right orthogonalise the columns of A = J V (V stays a rotation); the columns are
    sorted by norm (an odd permutation negates one, so det V = +1); then u₁, u₂ are the first two columns normalised,
    u₃ = u₁ × u₂ and S[2] = u₃ · a₃, the signed third singular value. Singular values to high relative accuracy
    (no JᵀJ is formed); U and V agree with LAPACK's up to the signs of pairs of columns and rotations within
    repeated singular values, which the eigensystem does not see.
    """
    A = U  # the columns of J V, normalised in place at the end
    for i in range(3):
        for j in range(3):
            A[i, j] = J[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(30):
        done = True
        for p, q in _PAIRS:
            al = A[0, p] ** 2 + A[1, p] ** 2 + A[2, p] ** 2
            be = A[0, q] ** 2 + A[1, q] ** 2 + A[2, q] ** 2
            ga = A[0, p] * A[0, q] + A[1, p] * A[1, q] + A[2, p] * A[2, q]
            if not abs(ga) > 2.3e-16 * math.sqrt(al * be):
                continue
            done = False
            zeta = (be - al) / (2 * ga)
            t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1 + zeta * zeta))
            c = 1 / math.sqrt(1 + t * t)
            s = c * t
            for M in (A, V):
                for k in range(3):
                    mp, mq = M[k, p], M[k, q]
                    M[k, p], M[k, q] = c * mp - s * mq, s * mp + c * mq
        if done:
            break
    for i in range(3):
        S[i] = math.sqrt(A[0, i] ** 2 + A[1, i] ** 2 + A[2, i] ** 2)
    _sort_columns(A, V, S)
    for c in range(2):
        if S[c] > 0:
            for i in range(3):
                A[i, c] /= S[c]
        elif c == 0:
            for i in range(3):
                A[i, 0] = 1.0 if i == 0 else 0.0
        else:
            _unit_orthogonal(A[:, 0], A[:, 1])
    a3 = (A[0, 2], A[1, 2], A[2, 2])
    A[0, 2] = A[1, 0] * A[2, 1] - A[2, 0] * A[1, 1]
    A[1, 2] = A[2, 0] * A[0, 1] - A[0, 0] * A[2, 1]
    A[2, 2] = A[0, 0] * A[1, 1] - A[1, 0] * A[0, 1]
    S[2] = A[0, 2] * a3[0] + A[1, 2] * a3[1] + A[2, 2] * a3[2]


@njit(**_JIT)
def _sort_columns(A, V, S):
    """Sort the columns of A and V by S descending; an odd permutation negates the last column of both (det V = +1)."""
    odd = False
    for i in range(2):
        k = i
        for j in range(i + 1, 3):
            if S[j] > S[k]:
                k = j
        if k != i:
            odd = not odd
            S[i], S[k] = S[k], S[i]
            for r in range(3):
                A[r, i], A[r, k] = A[r, k], A[r, i]
                V[r, i], V[r, k] = V[r, k], V[r, i]
    if odd:
        for r in range(3):
            A[r, 2], V[r, 2] = -A[r, 2], -V[r, 2]


@njit(**_JIT)
def energies(X, F, D, order, A, code, mu):
    """(E_μ, E) = Σ_t A_t (ψ_μ, ψ)(J_t) of the map X (n, d), d = 2 or 3, in one pass."""
    m, d = F.shape[0], X.shape[1]
    J, U, V, S = np.empty((d, d)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    T, d1, d2 = np.empty(3), np.empty(3), np.empty((3, 3))
    Es, Ee = 0.0, 0.0
    for t in range(m):
        if d == 2:
            _jacobian2(X, F, D, order, t, J)
            s1, s2 = _sigma2(J)
            smooth, exact = _value2(code, s1, s2, mu)
        else:
            _jacobian(X, F, D, order, t, d, J)
            svd3(J, U, S, V)
            smooth, exact = _sigma3(code, S, mu, T, d1, d2)
        Es += A[t] * smooth
        Ee += A[t] * exact
    return Es, Ee


@njit(**_JIT)
def grad_hess(X, F, D, order, A, code, mu, kink, hold, project, slot, g, data, W, lamA):
    """One Newton iteration's element work: returns E; writes ∇E into g (d n,), the Hessian's CSC values into data
    (nnz,), and ``local`` = (W (m, (d+1)d, d²), A_t λ (m, d²), unclamped) of ``ReducedProblem.grad_hess``.

    X (n, d) with d = 2 or 3, F (m, d+1), D (m, d+1, d) the hat gradients, order (m, d+1) of :func:`vertex_order`,
    A (m,) areas, kink (m, 2) per element (and kink set in 3D; read when ``hold``), slot (m, (d+1)d, (d+1)d) of
    :func:`slot_map`; ``project`` clamps the element eigenvalues of the assembled values at 0.
    """
    m, d = F.shape[0], X.shape[1]
    nm = d * d
    J, U, V, S = np.empty((d, d)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    grad, lam, lp = np.empty(nm), np.empty(nm), np.empty(nm)
    modes, v3, m3 = np.empty((nm, nm)), np.empty((6, 3)), np.empty((5, 3, 3))
    g[:] = 0.0
    data[:] = 0.0
    E = 0.0
    for t in range(m):
        if d == 2:
            _jacobian2(X, F, D, order, t, J)
            psi = eigen2(J, code, mu, kink[t, 0], hold, False, grad, lam, modes)
        else:
            _jacobian(X, F, D, order, t, d, J)
            svd3(J, U, S, V)
            psi = eigen3(U, S, V, code, mu, kink[t, 0], kink[t, 1], hold, grad, lam, modes, v3, m3)
        E += A[t] * psi
        if d == 2:
            _local2(D, t, A[t], grad, modes, g, F, W)
        else:
            _local(D, t, d, A[t], grad, modes, g, F, W)
        for q in range(nm):
            lamA[t, q] = lam[q] * A[t]
            lp[q] = max(lamA[t, q], 0.0) if project else lamA[t, q]
        if d == 2:
            _scatter2(W, lp, slot, t, data)
        else:
            _scatter_one(W, lp, slot, t, data)
    return E


@njit(**_JIT)
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
