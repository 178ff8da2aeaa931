"""Closed-form point-handle deformations that people use instead of DefOp: the peers of notebook 12.

Each method is split into a *precompute* on the rest mesh and rest handles P, and an *evaluate* that maps
handle positions Q to deformed vertex positions X, like ``DefOp.__call__``:

- MLS similarity and rigid: Schaefer, McPhail & Warren 2006, §2.2 (μ_s) and §2.3 (f_r); O(n h) per frame.
- Bookstein's thin-plate-spline warp: Bookstein 1989, §2 (U(r) = r² log r², the L matrix); X = G Q.
- BBW + LBS: Jacobson, Baran, Popović & Sorkine 2011 (libigl ``bbw``), translations only; X = V + W (Q − P).
- Biharmonic coordinates: Wang, Jacobson et al. 2015 (libigl ``biharmonic_coordinates``); X = W Q.
- ARAP iterations: Sorkine & Alexa 2007 (libigl ``arap_solve``); k local-global steps per frame.

Here P and Q hold *all* handles (h,d), fixed ones included; :func:`make_peer` wraps a method as a
:class:`Peer` that takes the moving handles only, as a DefOp does, so one harness
(:mod:`defop.analysis.compare`) times and scores them all.

Every method works on triangle meshes (d = 2) and tetrahedral meshes (d = 3), reading d from the data (the
columns of V, or ``mesh.dim``). The libigl methods take tets as they are (``arap_precomputation`` with dim 3,
``bbw`` and ``biharmonic_coordinates`` on tets). Only two closed forms depend on d:

- MLS in 3D is the weighted Procrustes fit of Zhu & Gortler 2007 (*3D deformation using moving least squares*):
  the covariance Σ_i w_i q̂_i p̂_iᵀ is linear in Q, and each vertex's rotation comes from its 3×3 SVD per frame
  (rigid), with the Procrustes scale for similarity. In 2D it is Schaefer et al.'s closed form, as before (the
  same map: the 2D optimal rotation in complex form).
- The TPS warp's kernel is the thin-plate (bending-energy) kernel of R^d: U = r² log r² in 2D (Bookstein),
  U = r in 3D (Duchon 1977; the 3D thin-plate spline). Both are conditionally positive definite of order ≤ 2,
  so the affine side conditions make Bookstein's L matrix invertible for handles that span R^d.

Point handles fix positions only: ARAP in 3D refuses handles on one line (a rotation about it is free), with the
solver's own rule (:func:`defop.variational.problem.check_handle_span`); linear precision (TPS, biharmonic
coordinates) needs handles that span R^d (not on one line in 2D, not on one plane in 3D).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import options as opt
from ..variational import problem

KINDS = ("mls-similarity", "mls-rigid", "tps", "bbw-lbs", "biharmonic", "arap")


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------
#: the largest MLS weight exponent α: w = |p − v|^{-2α} overflows float64 beyond it for distances of 1e-3 to 1e3
MAX_ALPHA = 50.0


def _dim_of(A):
    """d of a point array: its number of columns when that is 2 or 3, else 2 (the error then names (n, 2))."""
    shape = np.shape(A)
    return shape[1] if len(shape) == 2 and shape[1] in (2, 3) else 2


def _check_points(A, name, n=None, d=None):
    return opt.points(name, A, n=n, d=_dim_of(A) if d is None else d)


def _check_handles(P, min_count=1, method="this method", d=None):
    P = _check_points(P, "P", d=d)
    if len(P) < min_count:
        raise ValueError(f"{method} needs at least {min_count} handles, got {len(P)}")
    dist = np.linalg.norm(P[:, None] - P[None], axis=-1) + np.eye(len(P))
    i, j = np.unravel_index(np.argmin(dist), dist.shape)
    if len(P) > 1 and dist[i, j] < 1e-12 * max(1.0, np.abs(P).max()):
        raise ValueError(f"handles {min(i, j)} and {max(i, j)} coincide at {P[i].tolist()}")
    return P


def _check_Q(Q, h, d=2):
    Q = opt.real_array("Q", Q)
    if Q.shape != (h, d):
        raise ValueError(f"Q must have shape ({h}, {d}) for the {h} handles, got {Q.shape}{_dim_hint(Q, h, d)}")
    if not np.isfinite(Q).all():
        raise ValueError("Q has NaN or infinite entries")
    return Q


def _dim_hint(Q, h, d):
    """The clause naming a Q of h rows in the wrong dimension (a 2D Q for a 3D mesh, or the reverse), else ''."""
    return f" (a {d}D mesh needs {d}D handle positions)" if np.ndim(Q) == 2 and np.shape(Q)[0] == h else ""


#: what handles that fail to span k dimensions lie on
_FLAT = {0: "one point", 1: "one line", 2: "one plane"}


def _check_span(P, k, method, why):
    """Refuse handles P (h,d) whose affine hull has dimension < k (singular values of the centred P).

    ``method`` is the subject and verb of the message, e.g. ``"the TPS warp needs"``.
    """
    sv = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    if len(sv) < k or sv[k - 1] <= 1e-9 * max(sv[0], np.finfo(float).tiny):
        spread = f" (spread across it {sv[k - 1]:.2g}, along it {sv[0]:.2g})" if len(sv) >= k else ""
        raise ValueError(
            f"{method} handles that are not all on {_FLAT[k - 1]} ({why}); the {len(P)} handles "
            f"lie on {_FLAT[k - 1]}{spread}; move one off it"
        )


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
    V = _check_points(V, "V")
    dim = V.shape[1]
    P = _check_handles(P, dim, "MLS", d=dim)
    _check_span(P, dim - 1, "MLS needs", "the rotation about it would be undetermined")
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
    Q = _check_Q(Q, pre.Wn.shape[1], pre.d)
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
    V = _check_points(V, "V")
    d = V.shape[1]
    P = _check_handles(P, d + 1, "the TPS warp", d=d)
    h = len(P)
    Pt = np.hstack([np.ones((h, 1)), P])
    _check_span(P, d, "the TPS warp needs", "its affine part would be undetermined")
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
    return G @ _check_Q(Q, G.shape[1], _dim_of(Q) if d is None else d)


# ----------------------------------------------------------------------------------------------
# libigl: bounded biharmonic weights + LBS, biharmonic coordinates, ARAP iterations
# ----------------------------------------------------------------------------------------------
def _mesh_arrays(mesh, handles):
    V = np.ascontiguousarray(mesh.V, dtype=float)
    F = np.ascontiguousarray(mesh.F, dtype=np.int64)
    b = np.asarray(handles, dtype=np.int64).ravel()
    if len(b) == 0 or b.min() < 0 or b.max() >= len(V):
        raise ValueError(f"handles must be vertex indices in [0, {len(V)}), got {b.tolist()}")
    if len(np.unique(b)) != len(b):
        raise ValueError("a vertex is given as a handle twice")
    _check_handles(V[b])
    return V, F, b


def bbw_precompute(mesh, handles, max_iter=100):
    """Bounded biharmonic weights (Jacobson et al. 2011) of point handles, rows normalised to sum 1.

    Minimises Σ_i ∫ (Δw_i)² subject to w_i(p_j) = δ_ij, 0 ≤ w_i ≤ 1 (libigl ``bbw``, active set). With
    translations only, linear blend skinning is X = V + W (Q − P).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices.
    max_iter : int

    Returns
    -------
    W : (n,h) numpy array
    """
    import igl

    max_iter = opt.integer("max_iter", max_iter, minimum=1)  # libigl took 0 or -1 as its own default
    V, F, b = _mesh_arrays(mesh, handles)
    bc = np.eye(len(b))
    W = np.asarray(igl.bbw(V, F, b, bc, max_iter=max_iter))
    return W / W.sum(axis=1, keepdims=True)


def lbs_evaluate(V, W, P, Q):
    """Linear blend skinning with translations only: X = V + W (Q − P).

    Parameters
    ----------
    V : (n,d) numpy array
    W : (n,h) numpy array
    P, Q : (h,d) numpy array

    Returns
    -------
    X : (n,d) numpy array
    """
    return V + W @ (_check_Q(Q, W.shape[1], np.shape(V)[-1]) - P)


def biharmonic_precompute(mesh, handles, k=2):
    """Biharmonic coordinates (Wang, Jacobson et al. 2015; libigl ``biharmonic_coordinates``).

    Linearly precise coordinates W minimising the k-harmonic energy with the handles as the only
    constraints: X = W Q, and W P = V. On triangles (d = 2) or tetrahedra (d = 3).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices, at least d + 1 (libigl returns an empty matrix for fewer), spanning R^d.
    k : int
        2 for biharmonic (1 harmonic, 4 tetraharmonic). libigl 2.6.3 returns an empty matrix for k = 3
        (triharmonic) on every mesh and handle set tried (3 to 40 handles on the bar): refused with a message.

    Returns
    -------
    W : (n,h) numpy array

    Raises
    ------
    ValueError
        Fewer than d + 1 handles, handles all on one line in 2D or one plane in 3D (no linear precision:
        W P = V has no solution), k = 3
        or k not a positive integer, or libigl returning no coordinates.
    """
    import igl

    k = opt.integer("k", k, minimum=1)
    if k == 3:
        raise ValueError(
            "k = 3 (triharmonic) is not available: libigl's biharmonic_coordinates returns an empty "
            "matrix for k = 3; use k = 2 (biharmonic)"
        )
    V, F, b = _mesh_arrays(mesh, handles)
    d = V.shape[1]
    if len(b) < d + 1:
        raise ValueError(f"biharmonic coordinates need at least {d + 1} point handles (linear precision), got {len(b)}")
    _check_span(V[b], d, "biharmonic coordinates need", "linear precision: W P = V")
    W = np.asarray(igl.biharmonic_coordinates(V, F, [[int(i)] for i in b], int(k)))
    if W.shape != (len(V), len(b)) or not np.isfinite(W).all():
        raise ValueError(f"libigl biharmonic_coordinates failed (returned shape {W.shape})")
    return W


class ARAPIterations:
    """k local-global ARAP iterations per frame (libigl), warm-started from the previous frame.

    libigl's ``arap_solve`` has no convergence test: it always runs ``iterations`` steps. It minimises
    Σ_t A_t ‖J_t − R_t‖²_F (Sorkine & Alexa 2007, per element: triangle areas in 2D, tet volumes in 3D with
    ``arap_precomputation``'s dim 3), the ARAP energy (10), and may invert elements. In 3D the handles must not
    all lie on one line (:func:`defop.variational.problem.check_handle_span`: a rotation about it is free).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    iterations : int
    """

    def __init__(self, mesh, handles, iterations=10):
        import igl

        self._V, F, self._b = _mesh_arrays(mesh, handles)
        problem.check_handle_span(mesh, self._b)
        self._F = F  # libigl keeps references: hold the arrays
        self.iterations = opt.integer("iterations", iterations, minimum=1)
        self.data = igl.ARAPData()
        self.data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
        self.data.max_iter = self.iterations
        igl.arap_precomputation(self._V, self._F, self._V.shape[1], self._b, self.data)
        self.reset()

    def reset(self):
        """Start the next frame from the rest pose."""
        self.U = self._V.copy()

    def __call__(self, Q):
        """(n,d) positions after ``iterations`` steps from the previous frame, handles at Q (h,d)."""
        import igl

        Q = np.ascontiguousarray(_check_Q(Q, len(self._b), self._V.shape[1]))
        U = np.ascontiguousarray(self.U)
        U[self._b] = Q
        self.U = np.array(igl.arap_solve(Q, self.data, U))
        return self.U.copy()


# ----------------------------------------------------------------------------------------------
# one interface for all: Peer
# ----------------------------------------------------------------------------------------------
class Peer:
    """A peer method bound to a shape: ``peer(Q)`` maps the *moving* handles to (n,d) positions, like DefOp.

    Fixed handles stay at rest. Build one with :func:`make_peer`.

    Parameters
    ----------
    name : str
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
    moving : (h,) bool numpy array
    evaluate : callable
        (h,d) targets of all handles → (n,d) positions (d = ``mesh.dim``).
    precompute_time : float
        Seconds the precompute took.
    reset : callable, optional
        Forget the previous frame (stateful methods).
    """

    def __init__(self, name, mesh, handles, moving, evaluate, precompute_time, reset=None):
        self.name = name
        self.mesh = mesh
        self.handles = np.asarray(handles, dtype=np.int64)
        self.moving = np.asarray(moving, dtype=bool)
        self._evaluate = evaluate
        self.precompute_time = float(precompute_time)
        self._reset = reset

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    def __repr__(self):
        return f"Peer({self.name!r}, {self.n_vertices} vertices, {self.n_moving} moving handles)"

    def reset(self):
        """Forget the previous frame (only ARAP iterations have one)."""
        if self._reset is not None:
            self._reset()

    def __call__(self, Q):
        """Deformed vertices for the moving handles Q.

        Parameters
        ----------
        Q : (n_moving,d) or (k,n_moving,d) numpy array
            d = ``mesh.dim``. A batch is evaluated frame by frame, in order; k = 0 (an empty batch) gives an
            empty (0, n_vertices, d) result, as :class:`~defop.operator.defop.DefOp` does.

        Returns
        -------
        X : (n_vertices,d) or (k,n_vertices,d) numpy array

        Raises
        ------
        ValueError
            Q (any frame of a batch) of the wrong shape or with NaN, before any frame is evaluated: a stateful
            peer (ARAP iterations) is left as it was.
        """
        Q = opt.real_array("Q", Q)
        n, d = self.n_moving, self.mesh.dim
        if Q.shape[-2:] != (n, d) or Q.ndim not in (2, 3):
            raise ValueError(
                f"Q must have shape ({n}, {d}) or (k, {n}, {d}) for the {n} moving handles, "
                f"got {Q.shape}{_dim_hint(Q, n, d)}"
            )
        if not np.isfinite(Q).all():
            where = f" (frame {int(np.argwhere(~np.isfinite(Q))[0, 0])})" if Q.ndim == 3 else ""
            raise ValueError(f"Q has NaN or infinite entries{where}")
        if Q.ndim == 3:
            X = np.empty((len(Q), self.n_vertices, d))
            for k, q in enumerate(Q):
                X[k] = self._frame(q)
            return X
        return self._frame(Q)

    def _frame(self, Q):
        """(n_vertices,d) positions for one checked (n_moving,d) Q."""
        T = self.mesh.V[self.handles].copy()
        T[self.moving] = Q
        return self._evaluate(T)


def make_peer(shape, kind, iterations=10, alpha=1.0):
    """Precompute one peer method on a shape.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
        Its mesh and handles (all of them, fixed ones included).
    kind : str
        One of ``"mls-similarity"``, ``"mls-rigid"``, ``"tps"``, ``"bbw-lbs"``, ``"biharmonic"``, ``"arap"``.
    iterations : int
        Local-global iterations per frame for ``"arap"``.
    alpha : float
        MLS weight exponent.

    Returns
    -------
    peer : Peer
        With ``precompute_time`` measured.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown peer {kind!r}; known: {', '.join(KINDS)}")
    mesh, b = shape.mesh, shape.handles
    V, P = mesh.V, mesh.V[b]
    t0 = time.perf_counter()
    reset = None
    if kind.startswith("mls"):
        pre = mls_precompute(V, P, kind.split("-")[1], alpha)
        evaluate, name = (lambda T: mls_evaluate(pre, T)), f"MLS {pre.kind}"
    elif kind == "tps":
        G = tps_precompute(V, P)
        evaluate, name = (lambda T: linear_evaluate(G, T, mesh.dim)), "TPS warp (Bookstein)"
    elif kind == "bbw-lbs":
        W = bbw_precompute(mesh, b)
        evaluate, name = (lambda T: lbs_evaluate(V, W, P, T)), "BBW + LBS"
    elif kind == "biharmonic":
        G = biharmonic_precompute(mesh, b)
        evaluate, name = (lambda T: linear_evaluate(G, T, mesh.dim)), "biharmonic coordinates"
    else:
        arap = ARAPIterations(mesh, b, iterations)
        evaluate, name, reset = arap, f"libigl ARAP, {arap.iterations} it.", arap.reset
    seconds = time.perf_counter() - t0
    return Peer(name, mesh, b, shape.moving, evaluate, seconds, reset)


def make_peers(shape, kinds=KINDS, arap_iterations=(10,)):
    """Every peer of ``kinds`` on a shape, ARAP once per entry of ``arap_iterations``.

    Returns
    -------
    peers : list of Peer
    """
    if isinstance(arap_iterations, (str, bytes)) or not hasattr(arap_iterations, "__len__") or not len(arap_iterations):
        raise ValueError(f"arap_iterations must be a non-empty list of iteration counts, got {arap_iterations!r}")
    arap_iterations = [opt.integer("arap_iterations", k, minimum=1) for k in arap_iterations]
    out = []
    for kind in kinds:
        its = arap_iterations if kind == "arap" else (10,)
        out += [make_peer(shape, kind, iterations=k) for k in its]
    return out
