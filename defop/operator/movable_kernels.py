"""The single-frame finish of the movable-handle operator (:mod:`defop.operator.movable`) in one compiled call.

After the frame's u = X_z − X_(P,P) (two calls of :func:`defop.operator.kernels.tps_frame`, the second kept per
placement), one pass writes x + u, the residuals r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ), the correction Σ_ℓ g_{v_ℓ} r_ℓ on the
bumps' support, then the moving handles as q and the fixed ones as x; a frame with Q = P returns x. The same
arithmetic as :func:`defop.operator.movable.correct` (numba, BSD-2).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, boundscheck=False)
def finish_frame(Xz, X0, x, Q, Pm, idx, rows, hm, sup, wt, fixed):
    """(d n_vertices,) float64: x + (Xz − X0) corrected; Q, Pm (n, d); idx, rows (b,); hm (n,); sup (s,);
    wt (s, b); fixed (f,)."""
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
