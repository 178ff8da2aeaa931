"""The radial kernels φ of the ``"tps"`` handle basis (:class:`defop.operator.handle_bases.TPSBasis`).

The kernel depends on the dimension d of the handles (:data:`KERNELS`):

* d = 2: the paper's thin-plate spline φ(r) = r² log r on R^{2n}, exactly as before.
* d = 3: the polyharmonic spline φ(r) = r³ on R^{3n}. r² log r is the natural (polyharmonic) kernel of
  *even*-dimensional spaces; for odd dimension the polyharmonic splines are the odd powers r^{2k−1}, and
  R^{3n} is odd for every odd n. r³ is conditionally positive definite of order 2 in every dimension
  (Wendland, *Scattered Data Approximation*, Thm. 8.16: (−1)^⌈β/2⌉ r^β is CPD of order ⌈β/2⌉, here β = 3,
  sign +1, order 2), the same order as r² log r. So the linear side conditions of :meth:`side_conditions`
  still make the interpolation system uniquely solvable whenever the centres are unisolvent for affine
  functions, and the TPS operator reproduces every training deformation (Prop. 1); the reduced kernel
  matrix Qnᵀ K Qn is positive definite, so the fit's Cholesky path (:func:`defop.operator.fit.solve_structure_tps`)
  applies unchanged. φ(r) = r (CPD of order 1, but with sign −1: its reduced matrix is negative definite)
  would also interpolate, but it is not differentiable at the centres; r³ is C².
"""

from __future__ import annotations

import numpy as np

#: the radial kernel of the ``"tps"`` basis for each dimension d of the handles (module docstring)
KERNELS = {2: "r2logr", 3: "r3"}


def tps_phi(r2, out):
    """φ = r² log r = ½ r² log r² from squared distances ``r2`` (overwritten), written into ``out``."""
    r2[r2 <= 0] = 1.0  # at a centre (or rounded below 0): ½·1·log 1 = 0 = φ(0), exactly
    np.log(r2, out=out)
    out *= r2
    out *= 0.5


def cubic_phi(r2, out):
    """φ = r³ = r² √r² from squared distances ``r2`` (overwritten), written into ``out``."""
    r2[r2 <= 0] = 0.0  # at a centre (or rounded below 0): φ(0) = 0
    np.sqrt(r2, out=out)
    out *= r2


def tps_kernel(r):
    """φ(r) = r² log r with φ(0) = 0 (the d = 2 kernel)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, r * r * np.log(np.where(r > 0, r, 1.0)), 0.0)


def cubic_kernel(r):
    """φ(r) = r³ (the d = 3 kernel, see the module docstring)."""
    r = np.asarray(r, float)
    return r * r * r


def radial_kernel(d):
    """φ of the ``"tps"`` basis for handles in R^d: :func:`tps_kernel` (d = 2) or :func:`cubic_kernel` (d = 3)."""
    return {"r2logr": tps_kernel, "r3": cubic_kernel}[KERNELS[d]]


def first_duplicate(cz, tol):
    """The first pair (i, j), i < j in row-major order, of rows of cz (m, k) within ``tol``, or None.

    In blocks of rows, so the memory is about 4M numbers whatever m is (an (m, m, k) array would not fit for
    large m)."""
    m, k = cz.shape
    step = max(1, 2**22 // max(1, m * k))
    for i0 in range(0, m, step):
        d2 = np.sum((cz[i0 : i0 + step, None] - cz[None]) ** 2, axis=-1)
        dup = np.argwhere((d2 <= tol**2) & upper_mask(i0, d2.shape))
        if len(dup):
            return int(dup[0][0]) + i0, int(dup[0][1])
    return None


def upper_mask(i0, shape):
    """Mask of the entries (r, j) with j > i0 + r: the strict upper triangle of the block's rows."""
    return np.arange(shape[1])[None, :] > (i0 + np.arange(shape[0]))[:, None]
