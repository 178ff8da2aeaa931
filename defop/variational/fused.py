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

_JIT = {"cache": True, "nogil": True, "boundscheck": False}

#: the energies with a fused kernel, and their codes
CODES = {"arap": 0, "sarap": 1, "isometric": 2}
#: the dimensions with a fused kernel
DIMS = (2,)
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
def _frame2(J):
    """Signed singular values and frame of a 2×2 J (:func:`defop.variational.planar.svd_frame`)."""
    a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
    E, F, G, H = (a + d) / 2, (a - d) / 2, (c + b) / 2, (c - b) / 2
    Qn, Rn = math.hypot(E, H), math.hypot(F, G)
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
    return psi, 2 * t1 - 2 / _cube(t1), 2 * t2 - 2 / _cube(t2), 2 + 6 / (t1 * t1) ** 2, 2 + 6 / (t2 * t2) ** 2, 0.0, twist, flip


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
    rad = math.hypot(half, p12)
    ang = 0.5 * math.atan2(2 * p12, p11 - p22)
    c, s = math.cos(ang), math.sin(ang)
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
def element_values(X, F, D, order, code, mu):
    """(ψ_μ, ψ) per element (m,) of the map X (n, d): :func:`defop.variational.energies.density` with both."""
    m, d = F.shape[0], X.shape[1]
    J = np.empty((d, d))
    smooth, exact = np.empty(m), np.empty(m)
    for t in range(m):
        _jacobian(X, F, D, order, t, d, J)
        s1, s2 = _frame2(J)[:2]
        smooth[t], exact[t] = _value2(code, s1, s2, mu)
    return smooth, exact


@njit(**_JIT)
def energies(X, F, D, order, A, code, mu):
    """(E_μ, E) = Σ_t A_t (ψ_μ, ψ)(J_t) of the map X (n, d), one pass, nothing stored per element."""
    m, d = F.shape[0], X.shape[1]
    J = np.empty((d, d))
    Es, Ee = 0.0, 0.0
    for t in range(m):
        _jacobian(X, F, D, order, t, d, J)
        s1, s2 = _frame2(J)[:2]
        smooth, exact = _value2(code, s1, s2, mu)
        Es += A[t] * smooth
        Ee += A[t] * exact
    return Es, Ee


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


@njit(**_JIT)
def grad_hess(X, F, D, order, A, code, mu, kink, hold, project, slot, g, data, W, lamA):
    """One Newton iteration's element work: returns E; writes ∇E into g (d n,), the Hessian's CSC values into data
    (nnz,), and ``local`` = (W (m, (d+1)d, d²), A_t λ (m, d²), unclamped) of ``ReducedProblem.grad_hess``.

    X (n, d), F (m, d+1), D (m, d+1, d) the hat gradients, order (m, d+1) of :func:`vertex_order`, A (m,) areas, kink (m,) per-element thresholds (read
    when ``hold``), slot (m, (d+1)d, (d+1)d) of :func:`slot_map`.
    """
    m, d = F.shape[0], X.shape[1]
    nm = d * d
    J = np.empty((d, d))
    grad, lam, lp = np.empty(nm), np.empty(nm), np.empty(nm)
    modes = np.empty((nm, nm))
    g[:] = 0.0
    data[:] = 0.0
    E = 0.0
    for t in range(m):
        _jacobian(X, F, D, order, t, d, J)
        psi = eigen2(J, code, mu, kink[t], hold, False, grad, lam, modes)
        E += A[t] * psi
        _local(D, t, d, A[t], grad, modes, g, F, W)
        for q in range(nm):
            lamA[t, q] = lam[q] * A[t]
            lp[q] = max(lamA[t, q], 0.0) if project else lamA[t, q]
        _scatter_one(W, lp, slot, t, data)
    return E
