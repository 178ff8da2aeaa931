"""The closed-form rivals of DefOp: moving least squares (MLS) and the thin-plate-spline (TPS) warp.

- MLS similarity and rigid: Schaefer, McPhail & Warren 2006, §2.2 (μ_s) and §2.3 (f_r); O(n h) per frame. In 3D
  it is the weighted Procrustes fit of Zhu & Gortler 2007 (*3D deformation using moving least squares*): the
  covariance Σ_i w_i q̂_i p̂_iᵀ is linear in Q, and each vertex's rotation comes from its 3×3 SVD per frame
  (rigid), with the Procrustes scale for similarity. In 2D it is Schaefer et al.'s closed form (the same map: the
  2D optimal rotation in complex form).
- Bookstein's thin-plate-spline warp: Bookstein 1989, §2 (U(r) = r² log r², the L matrix); X = G Q. The kernel is
  the thin-plate (bending-energy) kernel of R^d: U = r² log r² in 2D (Bookstein), U = r in 3D (Duchon 1977; the
  3D thin-plate spline). Both are conditionally positive definite of order ≤ 2, so the affine side conditions
  make Bookstein's L matrix invertible for handles that span R^d.

Here P and Q hold *all* handles (h,d), fixed ones included (:func:`defop.rivals.peers.make_peer` binds them).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import options as opt
from .checks import check_handles, check_points, check_positions, check_span, dim_of

__all__ = [
    "MAX_ALPHA",
    "TPS_KERNELS",
    "MLSPrecomputed",
    "linear_evaluate",
    "mls_evaluate",
    "mls_precompute",
    "tps_precompute",
]

#: the largest MLS weight exponent α: w = |p − v|^{-2α} overflows float64 beyond it for distances of 1e-3 to 1e3
MAX_ALPHA = 50.0


# ----------------------------------------------------------------------------------------------
# Moving least squares (Schaefer, McPhail & Warren 2006)
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass
class MLSPrecomputed:
    """What MLS keeps between frames.

    Attributes
    ----------
    kind : str
        ``"similarity"`` or ``"rigid"``.
    M : (2n, 2h) numpy array or None
        2D: Σ_i q_i A_i(v) / μ(v) as a matrix on the stacked Q (μ = μ_s for similarity, 1 for rigid). None in 3D.
    Wn : (n, h) numpy array
        Normalised weights w_i / Σ_j w_j: q* = Wn Q.
    d_norm : (n,) numpy array
        |v − p*|, the length f_r keeps (rigid only).
    at_handle : (n,) int numpy array
        The handle a vertex sits on, or −1 (there the weights are infinite and f(v) = q_i).
    Wp : (n, h, 3) numpy array or None
        3D: w_i p̂_i, so that the covariance C(v) = Σ_i w_i q̂_i p̂_iᵀ = Σ_i q_i (w_i p̂_i)ᵀ (as Σ_i w_i p̂_i = 0).
    dv : (n, 3) numpy array or None
        3D: v − p*.
    mu : (n,) numpy array or None
        3D: μ_s = Σ_i w_i |p̂_i|² (the Procrustes scale's denominator).
    """

    kind: str
    M: np.ndarray | None
    Wn: np.ndarray
    d_norm: np.ndarray
    at_handle: np.ndarray
    Wp: np.ndarray | None = None
    dv: np.ndarray | None = None
    mu: np.ndarray | None = None

    @property
    def d(self) -> int:
        """The dimension of the points."""
        return 2 if self.Wp is None else self.Wp.shape[2]


def mls_precompute(V, P, kind="rigid", alpha=1.0):
    """Precompute MLS similarity or rigid deformation of the points V (Schaefer et al. 2006; 3D: Zhu & Gortler 2007).

    With weights w_i = 1 / |p_i − v|^{2α} (§2), centroids p* = Σ w_i p_i / Σ w_i, p̂_i = p_i − p*
    and q* likewise, and A_i = w_i [p̂_i; −p̂_i^⊥] [v − p*; −(v − p*)^⊥]^T (§2.2), the similarity
    deformation is f_s(v) = Σ_i q̂_i A_i / μ_s + q* with μ_s = Σ_i w_i |p̂_i|², and the rigid one (§2.3) is
    f_r(v) = |v − p*| f⃗_r(v) / |f⃗_r(v)| + q* with f⃗_r(v) = Σ_i q̂_i A_i. As Σ_i A_i = 0, Σ q̂_i A_i =
    Σ q_i A_i: both are linear in Q before the rigid normalisation, so a frame is one matrix product.

    In 3D the same maps are the weighted Procrustes fits f(v) = s R (v − p*) + q*, R the rotation and s the
    scale minimising Σ_i w_i |s R p̂_i − q̂_i|² (s = 1 for rigid): R from the SVD of C = Σ_i w_i q̂_i p̂_iᵀ
    = U S Vᵀ, R = U diag(1, 1, det U Vᵀ) Vᵀ, and s = tr(S diag(1, 1, det U Vᵀ)) / μ_s (Zhu & Gortler 2007).
    C is linear in Q; the 3×3 SVDs are per frame.

    Parameters
    ----------
    V : (n,d) numpy array
        The points to deform (mesh vertices or pixel centres), d = 2 or 3.
    P : (h,d) numpy array
        Rest handle positions, at least d (a similarity needs two points in 2D, three off one line in 3D),
        pairwise distinct.
    kind : str
        ``"similarity"`` or ``"rigid"``.
    alpha : float
        The weight exponent, 0 < α <= :data:`MAX_ALPHA`.

    Returns
    -------
    pre : MLSPrecomputed

    Raises
    ------
    ValueError
        ``alpha`` out of range, or so large for these distances that the weights overflow (never NaN); P not of
        V's dimension; in 3D, handles on one line (the rotation about it is undetermined).
    """
    if kind not in ("similarity", "rigid"):
        raise ValueError(f"kind must be 'similarity' or 'rigid', got {kind!r}")
    alpha = opt.positive("alpha", alpha, maximum=MAX_ALPHA)
    V = check_points(V, "V")
    dim = V.shape[1]
    P = check_handles(P, dim, "MLS", d=dim)
    check_span(P, dim - 1, "MLS needs", "the rotation about it would be undetermined")
    diff = P[None] - V[:, None]  # (n,h,d)
    r2 = np.einsum("nhc,nhc->nh", diff, diff)
    at = r2 <= 1e-24 * max(1.0, np.abs(P).max()) ** 2
    at_handle = np.where(at.any(axis=1), np.argmax(at, axis=1), -1)
    with np.errstate(over="ignore", divide="ignore", under="ignore"):
        w = 1.0 / np.where(at, 1.0, r2) ** alpha
    w[at_handle >= 0] = 0.0
    w[at_handle >= 0, at_handle[at_handle >= 0]] = 1.0  # any finite rows: these vertices are overwritten
    _check_weights(w, alpha)
    Wn = w / w.sum(axis=1, keepdims=True)
    p_star = Wn @ P
    ph = P[None] - p_star[:, None]  # p̂_i (n,h,d)
    d = V - p_star  # v − p*
    if dim == 3:  # the Procrustes form (closed-form place: the 2D one below is Schaefer's)
        mu = np.einsum("nh,nhc,nhc->n", w, ph, ph)
        mu[at_handle >= 0] = 1.0
        return MLSPrecomputed(kind, None, Wn, np.linalg.norm(d, axis=1), at_handle, w[..., None] * ph, d, mu)
    a = np.einsum("nhc,nc->nh", ph, d) * w  # w_i p̂_i·d
    c = (ph[..., 0] * d[:, None, 1] - ph[..., 1] * d[:, None, 0]) * w  # w_i p̂_i×d
    if kind == "similarity":
        mu = np.einsum("nh,nhc,nhc->n", w, ph, ph)
        mu[at_handle >= 0] = 1.0  # μ_s = 0 there; the row is overwritten by q_i
        a, c = a / mu[:, None], c / mu[:, None]
    # q A_i = (q_x a − q_y c, q_x c + q_y a), as rows 2v, 2v+1 over columns 2i, 2i+1
    n, h = a.shape
    M = np.empty((n, 2, h, 2))
    M[:, 0, :, 0], M[:, 0, :, 1] = a, -c
    M[:, 1, :, 0], M[:, 1, :, 1] = c, a
    return MLSPrecomputed(kind, M.reshape(2 * n, 2 * h), Wn, np.linalg.norm(d, axis=1), at_handle)


def _check_weights(w, alpha):
    """MLS weights must be finite with a positive sum per point: else α is too large for the distances."""
    sums = w.sum(axis=1)
    if not (np.isfinite(w).all() and np.isfinite(sums).all() and (sums > 0).all()):
        raise ValueError(
            f"alpha = {alpha!r} is too large for these handle distances: the MLS weights "
            f"|p - v|^(-2 alpha) overflow or vanish in float64; use a smaller alpha (1 is usual)"
        )


def _procrustes(pre, Q):
    """f(v) − q* = s R (v − p*) per point, from the SVD of C = Σ_i q_i (w_i p̂_i)ᵀ (see :func:`mls_precompute`)."""
    C = np.einsum("hc,nhe->nce", Q, pre.Wp)  # (n,d,d)
    U, S, Vt = np.linalg.svd(C)
    sign = np.sign(np.linalg.det(U @ Vt))  # ±1: U and Vᵀ are orthogonal
    U[..., -1] *= sign[:, None]  # R = U diag(1, .., det U Vᵀ) Vᵀ, a rotation
    R = U @ Vt
    f = np.einsum("ncd,nd->nc", R, pre.dv)
    if pre.kind == "similarity":
        S[:, -1] *= sign
        f *= (S.sum(axis=1) / pre.mu)[:, None]
    return f


def mls_evaluate(pre, Q):
    """MLS deformation f(V) for handle positions Q.

    Parameters
    ----------
    pre : MLSPrecomputed
    Q : (h,d) numpy array

    Returns
    -------
    X : (n,d) numpy array
    """
    Q = check_positions(Q, pre.Wn.shape[1], pre.d)
    if pre.M is None:
        f = _procrustes(pre, Q)
    else:
        f = (pre.M @ Q.ravel()).reshape(-1, 2)
        if pre.kind == "rigid":
            norm = np.linalg.norm(f, axis=1)
            f = f * (pre.d_norm / np.where(norm > 0, norm, 1.0))[:, None]
    X = f + pre.Wn @ Q
    on = pre.at_handle >= 0
    X[on] = Q[pre.at_handle[on]]
    return X


# ----------------------------------------------------------------------------------------------
# Bookstein's thin-plate-spline warp (1989)
# ----------------------------------------------------------------------------------------------
def _tps_kernel(r2):
    """U(r) = r² log r², with U(0) = 0 (Bookstein 1989, §2)."""
    return np.where(r2 > 0, r2 * np.log(np.where(r2 > 0, r2, 1.0)), 0.0)


def _tps_kernel_3d(r2):
    """U(r) = r, the thin-plate kernel of R³ (Duchon 1977): the fundamental solution of Δ² there is −r/(8π)."""
    return np.sqrt(r2)


#: the thin-plate kernel of R^d, as a function of r²: the one place the TPS warp depends on d
TPS_KERNELS = {2: _tps_kernel, 3: _tps_kernel_3d}


def tps_precompute(V, P):
    """Precompute the thin-plate-spline warp through the handles (Bookstein 1989; R³: Duchon's kernel U = r).

    f(x) = a_0 + Σ_c a_c x_c + Σ_i w_i U(|x − p_i|) with [K P̃; P̃^T 0] [w; a] = [Q; 0], K_ij = U(|p_i − p_j|)
    and P̃ = [1 p_i] (Bookstein's L matrix). The solution is linear in Q, so f(V) = G Q with
    G = [U(|V − P|) 1 V] L^{-1}[:, :h]. It interpolates the handles and reproduces affine maps exactly.
    U = r² log r² in 2D (Bookstein), U = r in 3D: each minimises the bending energy ∫ Σ |∂²f|² of its R^d, and
    each is conditionally positive definite of order ≤ 2, so L is invertible when the handles span R^d.

    Parameters
    ----------
    V : (n,d) numpy array
        d = 2 or 3.
    P : (h,d) numpy array
        At least d + 1 handles, not all on one line (2D) or one plane (3D).

    Returns
    -------
    G : (n,h) numpy array
    """
    V = check_points(V, "V")
    d = V.shape[1]
    P = check_handles(P, d + 1, "the TPS warp", d=d)
    h = len(P)
    Pt = np.hstack([np.ones((h, 1)), P])
    check_span(P, d, "the TPS warp needs", "its affine part would be undetermined")
    kernel = TPS_KERNELS[d]
    L = np.zeros((h + d + 1, h + d + 1))
    L[:h, :h] = kernel(np.sum((P[:, None] - P[None]) ** 2, axis=-1))
    L[:h, h:], L[h:, :h] = Pt, Pt.T
    rhs = np.vstack([np.eye(h), np.zeros((d + 1, h))])
    coef = np.linalg.solve(L, rhs)  # (h+d+1, h): [w; a] per unit handle displacement
    K = kernel(np.sum((V[:, None] - P[None]) ** 2, axis=-1))
    return K @ coef[:h] + np.hstack([np.ones((len(V), 1)), V]) @ coef[h:]


def linear_evaluate(G, Q, d=None):
    """X = G Q for a method linear in the handles (TPS warp, biharmonic coordinates).

    Parameters
    ----------
    G : (n,h) numpy array
    Q : (h,d) numpy array
    d : int, optional
        The dimension Q must have; by default Q's own (2 or 3).

    Returns
    -------
    X : (n,d) numpy array
    """
    return G @ check_positions(Q, G.shape[1], dim_of(Q) if d is None else d)
