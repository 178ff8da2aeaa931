"""The fused numba kernels of one tetrahedron: the signed 3×3 SVD and the eigensystem of
:mod:`defop.variational.volumetric` per element (the loops over elements are in :mod:`defop.variational.fused`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .fused_common import JIT, R2, finite

_PAIRS = ((0, 1), (0, 2), (1, 2))
_R3 = 1 / math.sqrt(3.0)
_R6 = 1 / math.sqrt(6.0)


@njit(**JIT)
def _w3(t):
    """w = u − v = (t − 1)² − (1/t − 1)² and its first two derivatives."""
    it3 = 1 / (t * t * t)
    return (t - 1) ** 2 - (1 / t - 1) ** 2, 2 * (t - 1) * (1 - it3), 2 - 6 * it3 / t + 4 * it3


@njit(**JIT)
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


@njit(**JIT)
def sigma3(code, S, mu, T, d1, d2):
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


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
def _on_set3(T, k, kink):
    """:func:`defop.variational.volumetric.on_kink` for one tetrahedron and kink set k (0: σ₁ = σ₂, 1: σ₂ = σ₃),
    T: σ with ones off the barrier's domain."""
    s = (T[k] + T[k + 1]) / 2
    it3 = 1 / (s * s * s)
    r = (s - 1) * (1 - it3) / math.sqrt(2.0)
    kappa = 1.5 + 1.5 * it3 / s - it3 if k == 0 else 0.5 + 4.5 * it3 / s - 3 * it3
    gap = T[k] - T[k + 1]
    return gap <= kink * T[k] and kappa * gap / math.sqrt(2.0) < r


@njit(**JIT)
def _hold_basis(a, b, Q):
    """The held σ-space basis of :data:`defop.variational.volumetric._HOLD_BASES` (columns) into Q (3, 3)."""
    r2 = R2
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


@njit(**JIT)
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


@njit(**JIT)
def eigen3(U, S, V, code, mu, kink0, kink1, hold, grad, lam, modes, v3, m3):
    """ψ; vec ∂ψ/∂J into grad (9,), eigenvalues into lam (9,), unit eigenvectors into the columns of modes (9, 9).

    :func:`defop.variational.volumetric.eigensystem` for one tetrahedron, from its signed SVD U diag(S) Vᵀ; v3 (6, 3)
    and m3 (5, 3, 3) are scratch."""
    T, d1, twist, flip, ls = v3[0], v3[1], v3[2], v3[3], v3[4]
    d2, E = m3[0], m3[1]
    psi = sigma3(code, S, mu, T, d1, d2)[0]
    _twist_flip3(code, T, d1, d2, mu, twist, flip)
    for i in range(3):
        for j in range(3):
            d2[i, j] = finite(d2[i, j])
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
            modes[r, 3 + k] = (U[p, j] * V[q, i] - U[p, i] * V[q, j]) * R2
            modes[r, 6 + k] = (U[p, i] * V[q, j] + U[p, j] * V[q, i]) * R2
    for k in range(3):
        lam[k] = ls[k]
        lam[3 + k] = twist[k] if np.isfinite(twist[k]) else -np.inf
        lam[6 + k] = flip[k]
    for q in range(9):
        lam[q] = finite(lam[q])
    return psi


@njit(**JIT)
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


@njit(**JIT)
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


@njit(**JIT)
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
