"""The compiled kernels of the closed-form operators (numba, BSD-2), named for what they compute.

* :func:`tps_frame`: one frame of a TPS operator, (★) of :mod:`defop.operator.defop` in one call (its parts
  :func:`tps_raw`, :func:`tps_rest`, :func:`frame_from_raw`, :func:`axpy8`, :func:`beyond_bound`);
* :func:`movable_frame`: one frame of a movable-handle operator (:mod:`defop.operator.movable`) in one call,
  :func:`tps_frame` and :func:`movable_correction`, the float64 finish.

A compressed frame streams B (rank × d n_vertices, float32: 1.1 MB for the aleph TPS-500 at rank 49) from
cache; numpy spends as long again in the dozen ufunc and BLAS calls around it (ψ: a gemv, two additions, a
log, a product and a subtraction; δψ A; t B; the cast; x added; the handles). Here the whole frame is one
numba call (BSD-2): the TPS raw values ℓ − ℓ(0) (:meth:`defop.operator.handle_bases.TPSBasis.delta_raw`),
t = δψ A', u = t B in float32 (B read once), then x + u in float64 and the handles' exact part, with no
temporary but the output. Measured in ``benchmarks/bench_frame.py``.

The guarantees do not depend on the kernel's arithmetic:

* (8b): at Q = P every distance is r² = |c|² + ε bit for bit (the other terms are exact zeros), so ℓ = ℓ(0)
  when ℓ(0) comes from the same function (:func:`tps_rest`, which runs :func:`tps_raw`), δψ = 0, t = 0, u = 0
  and the output is x exactly.
* Prop. 2: the handle columns are written last as x_h + (Q − P) in float64 (B and W_F are zero there).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = {"cache": True, "nogil": True, "boundscheck": False}


@njit(**_JIT)
def tps_raw(dz, zz, cm, czeps, inv_s2, ell0, log_kernel, y):
    """[dz, ℓ − ℓ(0)] into y (dn + m,): r² = |c|² + ε + |z|² − 2c·z, ℓ = r² log r² (d = 2) or r² √r² (d = 3).

    dz (dn,) float64, zz = |dz|², cm (dn, m) = −2c/scale, czeps (m,) = |c|² + ε, ell0 (m,) ℓ(0).
    """
    dn, m = cm.shape
    r2 = czeps + zz * inv_s2
    for i in range(dn):
        di = dz[i]
        for k in range(m):
            r2[k] += di * cm[i, k]
    for i in range(dn):
        y[i] = dz[i]
    for k in range(m):
        v = r2[k]
        ell = v * np.log(v) if log_kernel else v * np.sqrt(v)
        y[dn + k] = ell - ell0[k]


@njit(**_JIT)
def tps_rest(cm, czeps, inv_s2, log_kernel):
    """ℓ(0) (m,) by :func:`tps_raw` itself (its value at dz = 0 with ℓ(0) = 0)."""
    dn, m = cm.shape
    y = np.empty(dn + m)
    tps_raw(np.zeros(dn), 0.0, cm, czeps, inv_s2, np.zeros(m), log_kernel, y)
    return y[dn:].copy()


# fused multiply-adds ("contract"): the compressed frame's float32 round-off may differ in its last bits between
# CPUs with and without FMA (within the compression's own float32 error; handles and the rest pose stay exact)
@njit(**_JIT, fastmath={"contract"})
def axpy8(u, t, M):
    """u += t M (u (c,), t (k,), M (k, c) row-major), eight rows of M per pass over u: u is loaded and stored
    once per eight rows, as BLAS's gemv does (each element's sum is in a fixed order; fused multiply-adds)."""
    c, k1 = M.shape[1], M.shape[0]
    k = 0
    while k + 8 <= k1:
        a0, a1, a2, a3, a4, a5, a6, a7 = t[k], t[k + 1], t[k + 2], t[k + 3], t[k + 4], t[k + 5], t[k + 6], t[k + 7]
        for j in range(c):
            u[j] += (a0 * M[k, j] + a1 * M[k + 1, j] + a2 * M[k + 2, j] + a3 * M[k + 3, j]) + (
                a4 * M[k + 4, j] + a5 * M[k + 5, j] + a6 * M[k + 6, j] + a7 * M[k + 7, j]
            )
        k += 8
    while k < k1:
        a0 = t[k]
        for j in range(c):
            u[j] += a0 * M[k, j]
        k += 1


@njit(**_JIT)
def beyond_bound(dz, d, far2):
    """Whether a handle's |dz_j|² (dz (d n,), handles of d coordinates) reaches its bound far2[j]."""
    for j in range(far2.size):
        s = 0.0
        for i in range(d):
            s += dz[d * j + i] * dz[d * j + i]
        if s >= far2[j]:
            return True
    return False


@njit(**_JIT)
def frame_from_raw(y, A, B, x, hcols, xh, dz):
    """x + (y A) B (or x + y B when A has no rows) in float64, then x_h + dz at the handle columns.

    y (q,), A (q, r) row-major, B (r, c) row-major, both of y's dtype; x (c,) float64; hcols (h,), xh (h,),
    dz (h,). Returns the output (c,) float64.
    """
    if A.shape[0] > 0:
        t = np.zeros(A.shape[1], A.dtype)
        axpy8(t, y, A)
    else:
        t = y
    c = B.shape[1]
    u = np.zeros(c, B.dtype)
    axpy8(u, t, B)
    out = np.empty(c)
    for j in range(c):  # float64: x is never rounded to float32 (summing into a float64 out was 20% slower)
        out[j] = x[j] + u[j]
    for i in range(hcols.size):
        out[hcols[i]] = xh[i] + dz[i]
    return out


@njit(**_JIT)
def tps_frame(Q, P, R2, far2, cm, czeps, inv_s2, ell0, log_kernel, A, B, x, hcols, xh):
    """One frame of a TPS operator in one call: dz = (Q − P).ravel(), the guard, :func:`tps_raw`,
    :func:`frame_from_raw`.

    Q, P (n, d) float64; R2 the overflow guard on |dz|²; far2 (n,) the extrapolation bounds (or empty).
    Returns (out (c,), beyond): out is empty when |dz|² is not below R2 (NaN, inf, far: the caller takes the
    checked path); beyond tells whether a handle reached its far2 bound (:func:`beyond_bound`).
    """
    n, d = P.shape
    dz = np.empty(n * d)
    zz = 0.0
    for j in range(n):
        for i in range(d):
            v = Q[j, i] - P[j, i]
            dz[d * j + i] = v
            zz += v * v
    if not zz < R2:
        return np.empty(0), False
    far = far2.size > 0 and beyond_bound(dz, d, far2)
    y = np.empty(cm.shape[0] + cm.shape[1], B.dtype)
    tps_raw(dz, zz, cm, czeps, inv_s2, ell0, log_kernel, y)
    return frame_from_raw(y, A, B, x, hcols, xh, dz), far


@njit(**_JIT)
def movable_correction(Xz, X0, x, Q, Pm, idx, rows, hm, sup, wt, fixed):
    """x + (Xz − X0), corrected, of a movable-handle frame: (d n_vertices,) float64.

    After u = Xz − X0 (two calls of :func:`tps_frame`, X0 kept per placement), one pass writes x + u, the residuals
    r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ), the correction Σ_ℓ g_{v_ℓ} r_ℓ on the bumps' support, then the moving handles as q
    and the fixed ones as x; a frame with Q = P returns x. The same arithmetic as
    :func:`defop.operator.movable.correct`. Q, Pm (n, d); idx, rows (b,); hm (n,); sup (s,); wt (s, b); fixed (f,).
    """
    n, d = Pm.shape
    rest = True
    for j in range(n):
        for c in range(d):
            if Q[j, c] != Pm[j, c]:
                rest = False
    if rest:
        return x.copy()
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = x[i] + (Xz[i] - X0[i])
    b = idx.size
    r = np.empty((b, d))
    for ell in range(b):
        v, j = idx[ell], rows[ell]
        for c in range(d):
            r[ell, c] = (Q[j, c] - Pm[j, c]) - (Xz[v * d + c] - X0[v * d + c])
    for s in range(sup.size):
        base = sup[s] * d
        for ell in range(b):
            w = wt[s, ell]
            if w != 0.0:
                for c in range(d):
                    out[base + c] += w * r[ell, c]
    for j in range(n):
        for c in range(d):
            out[hm[j] * d + c] = Q[j, c]
    for f in range(fixed.size):
        for c in range(d):
            out[fixed[f] * d + c] = x[fixed[f] * d + c]
    return out


@njit(**_JIT)
def movable_frame(Q, Pm, zp, s_q, R2, far2, cm, czeps, inv_s2, ell0, log_kernel, A, B, x, X0, wt, ints):
    """One movable-handle frame in one call: z = [zp, (Q − Pm)/s_q], :func:`tps_frame` at z (the rest P = 0),
    then :func:`movable_correction` against the placement's frame X0.

    Q, Pm (n, d); zp (b, d) the placement's rest offsets (scaled); wt (s, B) the bumps of the B patch members;
    ints the placement's int arrays end to end: the members' vertices (B,), their rows of Q (B,), hm (n,),
    sup (s,), fixed (the rest). Returns (out, beyond) as
    :func:`tps_frame`: out is empty (the caller takes the checked path) when |z|² is not below R2 or X0 is empty.
    The same arithmetic as the two kernels called apart (z: one subtraction and one division per coordinate).
    """
    n, d = Pm.shape
    bz, b, s = zp.shape[0], wt.shape[1], wt.shape[0]
    z = np.empty((bz + n, d))
    z[:bz] = zp
    for j in range(n):
        for c in range(d):
            z[bz + j, c] = (Q[j, c] - Pm[j, c]) / s_q
    none = np.empty(0, np.int64)
    Xz, far = tps_frame(
        z, np.zeros((bz + n, d)), R2, far2, cm, czeps, inv_s2, ell0, log_kernel, A, B, x, none, np.empty(0)
    )
    if Xz.size == 0 or X0.size == 0:
        return np.empty(0), far
    h = 2 * b + n
    out = movable_correction(
        Xz, X0, x, Q, Pm, ints[:b], ints[b : 2 * b], ints[2 * b : h], ints[h : h + s], wt, ints[h + s :]
    )
    return out, far


def __getattr__(name):
    """The kernels' former names (deprecated): ``apply``, ``beyond``."""
    new = {"apply": "frame_from_raw", "beyond": "beyond_bound"}.get(name)
    if new is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import warnings

    warnings.warn(f"kernels.{name} is deprecated: use kernels.{new}", DeprecationWarning, stacklevel=2)
    return globals()[new]
