"""The signed SVD of 3×3 Jacobians (m,3,3), rotation-variant: σ₃ < 0 exactly when det J < 0.

The frame every energy of :mod:`defop.variational.volumetric` is written in (Irving, Teran & Fedkiw 2004).
"""

from __future__ import annotations

import numpy as np


def check_jacobians(J):
    """J as a float (m,3,3) array, finite; else a ValueError naming the shape or the non-finite entries."""
    J = np.asarray(J, dtype=float)
    if J.ndim != 3 or J.shape[1:] != (3, 3):
        raise ValueError(f"J must be an (m,3,3) array of 3×3 Jacobians, got shape {J.shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError("J must be finite, got NaN or inf entries")
    return J


def signed_svd(J):
    """Rotation-variant SVD J = U diag(S) Vᵀ of J (m,3,3): rotations U, V (m,3,3) and S (m,3), σ₁ ≥ σ₂ ≥ |σ₃|.

    σ₃ < 0 exactly when det J < 0. From LAPACK's SVD, a reflection in U or V moves into σ₃ (Irving, Teran & Fedkiw
    2004): the last column of U (of V) is negated where det U < 0 (det V < 0), and σ₃ with it, once per negation.
    """
    J = check_jacobians(J)
    U, S, Vt = np.linalg.svd(J)
    V = np.swapaxes(Vt, 1, 2).copy()
    for M in (U, V):
        neg = det3(M) < 0  # ±1 for these orthogonal matrices: the sign of the cofactor formula is exact
        M[neg, :, 2] *= -1
        S[neg, 2] *= -1
    return U, S, V


def det3(M):
    """det of 3×3 matrices M (m,3,3) by the cofactor formula (np.linalg.det's LU costs more on small matrices)."""
    return (
        M[:, 0, 0] * (M[:, 1, 1] * M[:, 2, 2] - M[:, 1, 2] * M[:, 2, 1])
        - M[:, 0, 1] * (M[:, 1, 0] * M[:, 2, 2] - M[:, 1, 2] * M[:, 2, 0])
        + M[:, 0, 2] * (M[:, 1, 0] * M[:, 2, 1] - M[:, 1, 1] * M[:, 2, 0])
    )


def signed_singular_values(J):
    """The signed singular values S (m,3) of :func:`signed_svd` without U and V: σ₃ < 0 exactly when det J < 0.

    LAPACK without singular vectors (cheaper); the same values up to round-off (a few ulps of σ₁)."""
    J = check_jacobians(J)
    S = np.linalg.svd(J, compute_uv=False)
    S[:, 2] *= np.where(det3(J) < 0, -1.0, 1.0)
    return S


def svd_frame(J):
    """Signed singular values and frame of 3×3 matrices: (S, U, V) of :func:`signed_svd`."""
    U, S, V = signed_svd(J)
    return S, U, V
