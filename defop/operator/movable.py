"""Handles that move at rest: the operator D(x; P, Q) (§5's last open question).

The rest positions of the *movable* handles (:mod:`defop.scene.placement`) are inputs. The operator is

    D(·; P, Q) = x + δψ(P, Q) W_F + Σ_ℓ g_{v_ℓ} r_ℓ,     δψ(P, Q) = Ψ(z(P, Q)) − Ψ(z(P, P))            (M)

* Ψ is the thin-plate spline basis (:class:`defop.operator.handle_bases.TPSBasis`, kernel r² log r in 2D) on the
  joint space z = [(P_b − P_b⁰)/s_P, (Q − P)/s_Q] ∈ R^{d(b + n)}: the b movable handles' rest offsets from
  their nominal vertices and the n moving handles' displacements. Its data are the training pairs (P_k, Q_k)
  *and* their rest poses (P_k, P_k) (and the nominal rest), with values the displacements X_k − x and 0. By
  default (:func:`centre_count`) m + 1 of these points, farthest first, carry a TPS function, as many as a fixed-P
  operator of m samples has, and f = Ψ W fits the others by least squares (the nominal rest exactly): the frame
  pays one logarithm per centre. With every point a centre (``centres=None``) f interpolates: 0 at every sampled
  rest pose, every training pair reproduced (Prop. 1).
* δψ subtracts Ψ at (P, P) from the same code on the same bits: at Q = P the two are equal and δψ = 0, so
  D(·; P, P) = x bit for bit (8b), whatever precision W_F is stored in; the rows of a batch at rest are also set
  to x explicitly (a gemm does not promise equal rows equal bits).
* r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ) is handle ℓ's residual at its vertex v_ℓ, computed in float64 from the same u the
  frame adds (float32 products are cast first), and g_v the placement's bump (1 at v, 0 at the other regions'
  vertices and at every handle that is not movable). Then the handle rows are written as q_ℓ exactly (Prop. 2,
  bit for bit), as are non-movable moving handles (q) and fixed handles (x); W_F is 0 on their columns.
* Affine precision: a displacement field affine in (Q − P) with coefficients independent of P is reproduced
  (the affine part of Ψ); the P-affine part cancels in δψ. Between samples D is a least-squares TPS fit on
  m + 1 centres (with ``centres=None`` every joint point is a centre and D interpolates every training pair).

In 3D a movable handle is a patch (:attr:`defop.scene.placement.PlacementRegions.members`): P names the movable
handle's vertex, every member moves with it by the same rest offset, z keeps one row per patch, and every member
is a handle ℓ of the correction and of Prop. 2 (W_F is not 0 on its columns: its vertex changes with P).

Batch semantics: one P per call; Q (n, d) or a batch (k, n, d) at that P. P is given for the movable handles
only: (b,) vertex indices or (b, d) points (snapped within :data:`defop.scene.placement.SNAP_TOL` of the bbox
diagonal). Extrapolation is judged on Q − P against the training offsets Q_k − P_k. When a rest handle moves while
the shape is deformed, :func:`retarget` keeps q − p (the handle's displacement travels with it); the operator
itself is a function of (P, Q) and keeps no state.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from . import compress as compress_mod
from . import core
from . import handle_bases as hb
from . import io as io_mod
from .core import EXTRAPOLATION_FACTOR, ExtrapolationWarning, OperatorCore, fast_matrices  # noqa: F401  (exported)
from .fit import centre_count, farthest_points, structure
from .io.movable_file import FORMAT, MEMBERS, save_movable  # noqa: F401  (public names)

#: rest placements a :class:`MovableOp` keeps resolved (keys: P as given and its vertices)
PLACEMENTS_KEPT = 32

#: :meth:`MovableOp.compress`'s tolerance: δψ spans every placement, so at the fixed-P 5e-3 the rank is 2-3x the
#: fixed-P one (aleph m = 500: ranks 69, 41, 27 at 5e-3, 1e-2, 2e-2 against 29; frame 5.3x, 3.0x, 1.7x; error same)
COMPRESS_TOL = 2e-2


@dataclasses.dataclass
class RestPlacement:
    """The state of one rest placement P of the movable handles (:meth:`MovableOp.at`,
    :meth:`.movable_carry.CarryOp.at`): ``idx`` (b,) the movable handles' vertices, ``hm`` (n,) the moving handles'
    vertices, ``P`` (n, d) their rest positions, ``bumps`` the placement's bumps (support, weights (s, B)),
    ``moved`` (B,) the vertices of every member of the movable patches (:attr:`PlacementRegions.moved`) and ``rows``
    (B,) their rows of Q; for :class:`MovableOp` also the factors it was made for (``key``), z(P, P) (``z0``), δψ's
    subtrahend (``psi0``), the kernel's frame at (P, P) (``X0``), the fixed handles, whether P is the nominal
    placement and the frame kernel's packed arguments (``zp`` = z0[:b], ``ints`` = moved, rows, hm, the bumps'
    support and the fixed handles end to end); for :class:`.movable_carry.CarryOp` the barycentric map ``S`` and the
    shift of Q to the nominal operator.
    """

    idx: np.ndarray
    hm: np.ndarray
    P: np.ndarray
    bumps: tuple
    key: object = None
    z0: np.ndarray | None = None
    psi0: np.ndarray | None = None
    X0: np.ndarray | None = None
    rows: np.ndarray | None = None
    fixed: np.ndarray | None = None
    nominal: bool = False
    S: object = None
    shift: np.ndarray | None = None
    zp: np.ndarray | None = None
    ints: np.ndarray | None = None
    moved: np.ndarray | None = None

    def __getitem__(self, name):
        """``state["idx"]``: the mapping access of earlier versions."""
        return getattr(self, name)


def joint_z(V, nominal, idx, handles_moving, Q, s_p, s_q):
    """The joint coordinates z (k, b + n, d) of rest vertices ``idx`` (b,) and Q (k, n, d).

    ``handles_moving`` (n,) are the moving handles' vertices with the movable ones at ``idx``.
    """
    a = (V[idx] - V[nominal]) / s_p  # (b, d)
    bq = (Q - V[handles_moving]) / s_q  # (k, n, d)
    return np.concatenate([np.broadcast_to(a, (len(bq), *a.shape)), bq], axis=1)


def joint_points(mesh, placement, moving, idx, Q, p_weight=1.0):
    """The joint samples' coordinates z in Ψ's space, with the scales that make them (the one rule of
    :func:`fit_movable` and of the spread design, :func:`defop.training.movable.spread_joint`): s_P the RMS rest
    offset |P_b − P_b⁰| over ``p_weight``, s_Q the RMS displacement |Q − P| (1 where they are 0).

    Parameters
    ----------
    idx : (m, b) int numpy array
    Q : (m, n, d) numpy array

    Returns
    -------
    zs : (m, b + n, d) numpy array
    scales : (s_P, s_Q)
    off_q : (m, n, d) numpy array
        The displacements Q − P.
    """
    hm = np.array([placement.handles_at(i)[moving] for i in idx])  # (m, n)
    off_p = mesh.V[idx] - mesh.V[placement.nominal]
    off_q = Q - mesh.V[hm]
    s_p = (float(np.sqrt(np.mean(np.sum(off_p**2, axis=-1)))) or 1.0) / p_weight
    s_q = float(np.sqrt(np.mean(np.sum(off_q**2, axis=-1)))) or 1.0
    return np.concatenate([off_p / s_p, off_q / s_q], axis=1), (s_p, s_q), off_q


def rest_centres(zs, b):
    """The distinct rest poses (P_k, P_k) of joint samples zs (m, b + n, d), the nominal (0) first: (r, b + n, d)."""
    z0 = zs.copy()
    z0[:, b:] = 0.0
    flat = np.unique(z0.reshape(len(z0), -1), axis=0)
    flat = flat[np.any(flat != 0.0, axis=1)]
    return np.concatenate([np.zeros((1, *zs.shape[1:])), flat.reshape(-1, *zs.shape[1:])])


def fit_movable(mesh, handles, moving, placement, idx, Q, X, meta=None, p_weight=1.0, centres="auto"):
    """Fit (M): a TPS of the displacements over the joint space, by least squares on m + 1 centres by default
    (interpolation with every joint point a centre).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles, moving : (h,) arrays of the nominal shape
    placement : defop.scene.placement.PlacementRegions
    idx : (m, b) int numpy array
        The movable handles' rest vertices of each sample.
    Q : (m, n, d) numpy array
    X : (m, n_vertices, d) numpy array
        The verified solutions of problem (6) with the handles at those vertices.
    centres : "auto", int or None, optional
        How many of the joint points (the rest poses and the samples) carry a TPS function, picked farthest
        first from the nominal rest (:func:`farthest_points`); the others are fitted by least squares
        (:func:`structure`, the nominal rest still exact). Fewer centres: a cheaper frame (each centre costs the
        frame a logarithm and a row of δψ A). ``"auto"`` (default): one per sample (:func:`centre_count`);
        None: all (interpolation: every training pair reproduced, Prop. 1).

    Returns
    -------
    MovableOp
    """
    idx = np.asarray(idx, np.int64)
    Q, X = np.asarray(Q, float), np.asarray(X, float)
    m, n, d = Q.shape
    if idx.shape != (m, placement.n_movable) or X.shape != (m, mesh.n_vertices, d):
        raise ValueError(f"idx must be (m, {placement.n_movable}) and X (m, {mesh.n_vertices}, {d}) for m = {m}")
    zs, (s_p, s_q), off_q = joint_points(mesh, placement, moving, idx, Q, p_weight)
    rc = rest_centres(zs, placement.n_movable)
    points = np.concatenate([rc, zs])
    k = centre_count(centres, m, len(points))
    keep = slice(None) if k >= len(points) else np.sort(farthest_points(points, k))
    Y = np.concatenate([np.zeros((len(rc), mesh.n_vertices * d)), (X - mesh.V).reshape(m, -1)])
    psi = hb.TPSBasis(np.zeros(zs.shape[1:]), points[keep], 1.0)
    G, _ = structure(psi, points)
    W = G @ Y  # the rest pose's data is 0: β Y[0] drops
    meta = {**(meta or {}), "basis": "tps-joint", "n_samples": m, "n_rest_centres": len(rc)}
    if k < len(points):
        meta["n_centres"] = len(psi.centers)
    return MovableOp(mesh, handles, moving, placement, psi, W, (s_p, s_q), meta, reach_of(off_q))


def reach_of(off_q):
    """Per moving handle, the farthest training offset |Q_k − P_k| (n,)."""
    return np.linalg.norm(off_q, axis=-1).max(axis=0)


def retarget(Q, placement, old, new):
    """Q after movable rest handles move from vertices ``old`` to ``new`` (b,) while deformed: q − p stays, for
    every member of their patches (3D).

    Returns
    -------
    Q : (n, d) numpy array
    """
    Q = np.array(Q, float)
    V, rows = placement.mesh.V, placement.moved_rows()
    Q[rows] = V[placement.members_at(new)] + (Q[rows] - V[placement.members_at(old)])  # at rest: V[new], exactly
    return Q


def correct(mesh, placement, handles, moving, st, u, Qs):
    """x + u, the residual correction Σ_ℓ g_{v_ℓ} r_ℓ in float64, the handles written exactly, rest rows = x.

    ``st``: the :class:`RestPlacement` of :meth:`MovableOp.at` (or :meth:`.movable_carry.CarryOp.at`); u (k, d n)
    float64, Qs (k, n, d). Returns (k, d n_vertices).
    """
    k, d, n_vertices = len(Qs), mesh.dim, mesh.n_vertices
    X = (mesh.V.ravel() + u).reshape(k, n_vertices, d)
    disp = Qs - st.P  # (k, n, d)
    r = disp[:, st.rows] - u.reshape(k, n_vertices, d)[:, st.moved]  # (k, B, d)
    sup, wt = st.bumps
    X[:, sup] += np.matmul(wt, r)  # (s, B) @ (k, B, d): Σ_ℓ g_{v_ℓ} r_ℓ on the bumps' support
    X[:, st.hm] = Qs  # Prop. 2: every moving handle on its target, bit for bit
    fixed = handles[~moving]
    X[:, fixed] = mesh.V[fixed]
    rest = ~np.any(disp.reshape(k, -1) != 0.0, axis=1)
    X[rest] = mesh.V  # (8b): D(·; P, P) = x bit for bit on every path
    return X.reshape(k, -1)


def residual(op, Q, P=None):
    """The largest |r_ℓ| (before the correction) of one frame, relative to the bbox diagonal: how far the fitted
    part alone misses the handles."""
    st = op.at(P)
    Q = np.asarray(Q, float)[None]
    u = op.displacement(Q, st)
    r = (Q - st.P)[:, st.rows] - u.reshape(1, op.n_vertices, op.d)[:, st.moved]
    return float(np.abs(r).max() / op.mesh.bbox_diagonal)


class MovableOp(OperatorCore):
    """D(x; P, Q) of (M) in the module docstring: a closed-form operator whose movable rest handles are inputs.

    Parameters
    ----------
    mesh, handles, moving
        The nominal shape's mesh and handles.
    placement : defop.scene.placement.PlacementRegions
    basis : defop.operator.handle_bases.TPSBasis
        Ψ on the joint space (pseudo-handles (b + n, d) at 0, scale 1).
    W : (|Ψ|, d n_vertices) numpy array
    scales : (s_P, s_Q)
    meta : dict
    reach : (n,) numpy array
        The farthest training offset per moving handle (the extrapolation warning).
    """

    #: the float32 rule's bound on a row of δψ (raw units) before it is scaled (:func:`core.reduced_product`)
    F32_ROW_BOUND = 1.0

    def __init__(self, mesh, handles, moving, placement, basis, W, scales, meta=None, reach=None):
        self.setup_core(mesh, handles, moving, W, meta)
        self.placement, self.basis = placement, basis
        self.scales = (float(scales[0]), float(scales[1]))
        self.reach = None if reach is None else np.asarray(reach, float)
        still = np.setdiff1d(np.arange(len(self.handles)), placement.moved)
        self.still = self.handles[still]  # handles that never leave their vertex (a movable patch's members do)
        self.set_free_part(self.still)
        self._placements = core.KeptPlacements(PLACEMENTS_KEPT)

    def __repr__(self):
        comp = f", rank {self.rank}" if self.factors is not None else ""
        return (
            f"MovableOp({self.meta.get('shape', '?')}, {self.placement.n_movable} movable of {self.n_moving} "
            f"moving handles, |Ψ|={self.basis.size}, {self.meta.get('n_samples')} samples{comp})"
        )

    # ------------------------------------------------------------------ the rest placement
    def at(self, P=None):
        """The state of rest placement P (:meth:`PlacementRegions.resolve`): its vertices, the moving handles' rest
        positions, z(P, P) and the kernel's frame at (P, P).

        P is checked and resolved once (:class:`core.KeptPlacements`: kept under P as given, bit for bit, and
        under its vertices, for the last :data:`PLACEMENTS_KEPT` placements and the current factors), so a frame
        at a placement seen before (an interactive drag) resolves nothing.
        """
        return self._placements.get(P, self.factors, self.placement.resolve, self._placement_state)

    def _placement_state(self, idx):
        """The :class:`RestPlacement` of the region vertices ``idx`` (b,), resolved."""
        hm = self.placement.handles_at(idx)[self.moving]
        Pm = self.mesh.V[hm]
        z0 = joint_z(self.mesh.V, self.placement.nominal, idx, hm, Pm[None], *self.scales)[0]
        st = RestPlacement(
            idx=idx,
            hm=hm,
            P=Pm,
            bumps=self.placement.bumps_at(idx),
            key=self.factors,
            z0=z0,
            rows=self.placement.moved_rows(),
            fixed=self.handles[~self.moving],
            nominal=bool(np.array_equal(idx, self.placement.nominal)),
            moved=self.placement.members_at(idx),
        )
        st.psi0 = self.basis.delta_z(z0.reshape(1, -1))  # (1, |Ψ|−1), float64
        st.X0 = self._kernel(z0, self.fast_state())
        st.zp = np.ascontiguousarray(z0[: len(idx)])
        sup = st.bumps[0]
        st.ints = np.concatenate([st.moved, st.rows, hm, sup, st.fixed]).astype(np.int64)
        return st

    def make_fast_state(self):
        """The :class:`core.FastState` of the joint basis; ``extra``: the kernel's empty handle arguments. The
        kernel's reach bounds are on z's rows: none on the b rest offsets, :func:`core.far_bound` / s_Q² on the n
        moving handles' (a frame flagged beyond them runs the full extrapolation check)."""
        f = fast_matrices(self.basis, self._WF, self.factors)
        far2 = core.far_bound(self.reach)
        if far2 is not None:
            far2 = np.concatenate([np.full(self.placement.n_movable, np.inf), far2 / self.scales[1] ** 2])
        f.kernel = core.kernel_args(self.basis, f.mats, far2)
        f.extra.update(zero=np.zeros(self.basis.P.shape), none=np.zeros(0, np.int64), nothing=np.zeros(0))
        return f

    def _kernel(self, z, f):
        """x + (ψ_raw(z) − ℓ(0)) A' B by the compiled frame (empty when beyond the overflow guard)."""
        k, e = f.kernel, f.extra
        return k.lib.tps_frame(z, e["zero"], f.R2, k.far2, *k.tps, k.A, k.B, self._x, e["none"], e["nothing"])[0]

    # ------------------------------------------------------------------ evaluation
    def _check_Q(self, Q, st):
        n = self.n_moving
        Q = core.check_configurations(Q, n, self.d)  # the one check of Q: shape, real, finite
        if self.reach is not None:
            diff = Q - st.P
            if np.vdot(diff, diff) < 1e300:  # vdot: no overflow warning; below, no square overflows (the frame's case)
                dist = np.sqrt(np.square(diff).sum(axis=-1).reshape(-1, n).max(axis=0, initial=0.0))
            else:
                with np.errstate(over="ignore"):  # a far Q: inf, refused where Ψ is evaluated
                    dist = np.sqrt(np.square(diff).sum(axis=-1).reshape(-1, n).max(axis=0, initial=0.0))
            far = np.flatnonzero(core.beyond_reach(dist, self.reach))
            if far.size:
                j = int(far[0])
                warnings.warn(
                    core.extrapolation_message(
                        j, dist[j], self.reach[j], "its rest position P", "the farthest training offset"
                    ),
                    ExtrapolationWarning,
                    stacklevel=3,
                )
        return Q

    def __call__(self, Q, P=None):
        """D(·; P, Q): (n_vertices, d), or (k, n_vertices, d) for a batch Q (k, n, d) at one P, in float64.

        Uncompressed: float64 W_F. Compressed: the factors (one frame by the compiled kernel). An empty batch gives
        (0, n_vertices, d); a Q so far that Ψ is not finite raises ValueError naming Q.
        """
        st = self.at(P)
        Q = self._check_Q(Q, st)
        empty = core.empty_frames(Q, self.n_vertices, self.d)
        if empty is not None:
            return empty
        Q2 = Q.reshape(-1, self.n_moving, self.d)
        if self.factors is not None and Q.ndim == 2:
            return self._one_frame(Q, st)
        out = self._finish(self.displacement(Q2, st), st, Q2)
        return out.reshape(*Q.shape[:-2], self.n_vertices, self.d)

    def delta_psi(self, Qs, st):
        """δψ(P, Q_k) (k, |Ψ|−1) in float64, checked finite (a ValueError naming Q where Ψ overflows)."""
        z = joint_z(self.mesh.V, self.placement.nominal, st.idx, st.hm, Qs, *self.scales)
        with np.errstate(over="ignore", invalid="ignore"):  # a far Q: the clear error below, not numpy's warning
            dpsi = self.basis.delta_z(z.reshape(len(z), -1)) - st.psi0
        core.check_finite(dpsi, Qs, st.P, self.basis, self.mesh)
        return dpsi

    def displacement(self, Qs, st):
        """u = δψ(P, Q_k) W_F (k, d n_vertices) in float64 (the factors' product when compressed), no correction."""
        dpsi = self.delta_psi(Qs, st)
        if self.factors is None:
            return dpsi @ self._WF
        return self._product(dpsi)

    def _product(self, dpsi):
        """δψ (k, |Ψ|−1) times the fast matrices (float32 W_F or the factors) by the one float32 rule, float64."""
        mats = self.fast_state().mats
        y = core.reduced_product(dpsi / self.basis.raw_scale, mats, self.F32_ROW_BOUND)
        return y.astype(float)

    def _frame(self, Q, st):
        """One frame of a float64 Q (n, d) by :func:`kernels.movable_frame` (z = [(P_b − P_b⁰)/s_P, (Q − P)/s_Q]
        with the rest offsets kept per placement): (X (n_vertices, d), or None beyond the float32 guard, and
        whether a handle reached the kernel's reach bound)."""
        f = self._fast if self._fast is not None and self._fast.key is self.factors else self.fast_state()
        k = f.kernel
        X, far = k.lib.movable_frame(
            Q, st.P, st.zp, self.scales[1], f.R2, k.far2, *k.tps, k.A, k.B, self._x, st.X0, st.bumps[1], st.ints
        )
        return (X.reshape(self.n_vertices, self.d) if X.size else None), far

    def _one_frame(self, Q, st):
        """One frame of a checked Q: the kernel, or beyond its guard numpy with scaling, Ψ checked finite."""
        X, _ = self._frame(Q, st)
        if X is None:
            u = self._product(self.delta_psi(Q[None], st))
            X = self._finish(u, st, Q[None])[0].reshape(self.n_vertices, self.d)
        return X

    def evaluate_fast(self, Q, P=None):
        """One frame by the compiled kernel: float32 W_F (or the factors), the correction in float64.

        P is checked once per placement (:meth:`at`). Q is checked in full only when it must be: a float64 array
        of the frame's shape (:func:`core.fast_input`) goes to the kernel, whose guard sends NaN, inf and far Q to
        the full check (a ValueError naming Q) and whose reach bound to the extrapolation check (the warning).
        """
        st = self.at(P)
        if core.fast_input(Q, st.P.shape):
            X, far = self._frame(Q, st)
            if X is not None:
                if far:
                    self._check_Q(Q, st)  # the full check decides (and words the warning)
                return X
        Q = self._check_Q(Q, st)
        if Q.shape != st.P.shape:
            raise ValueError(f"Q must have shape {st.P.shape} (one frame), got {Q.shape}")
        return self._one_frame(Q, st)

    def evaluate_batch(self, Qs, P=None):
        """D(·; P, Q_k) for a batch Qs (k, n, d) at one P: float32 products, the correction in float64."""
        st = self.at(P)
        Qs = self._check_Q(Qs, st)
        if Qs.ndim != 3:
            raise ValueError(f"Qs must have shape (k, {self.n_moving}, {self.d}), got {Qs.shape}")
        if len(Qs) == 0:
            return core.empty_frames(Qs, self.n_vertices, self.d)
        u = self._product(self.delta_psi(Qs, st))
        return self._finish(u, st, Qs).reshape(len(Qs), self.n_vertices, self.d)

    def _finish(self, u, st, Qs):
        return correct(self.mesh, self.placement, self.handles, self.moving, st, u, Qs)

    # ------------------------------------------------------------------ compression and files
    def compress(self, rank=None, tol=COMPRESS_TOL, dtype=np.float32, samples=None):
        """W_F ≈ A B (:func:`defop.operator.compress.principal_factors`), the directions of δψ at ``samples``
        (joint z rows, (m, |Ψ|−1) δψ; default the basis' centres), to ``tol`` (default :data:`COMPRESS_TOL`);
        the guarantees stay exact. Returns self."""
        return self.set_factors(self.factorise(rank, tol, dtype, samples))

    def factorise(self, rank=None, tol=COMPRESS_TOL, dtype=np.float32, samples=None):
        """The factors (A, B) :meth:`compress` would set; ``self`` is unchanged."""
        S = self.compression_samples() if samples is None else samples
        return compress_mod.free_factors(self, self.still, S, rank, tol, compress_mod.check_options(rank, tol, dtype))

    def compression_samples(self):
        """δψ (|C|, |Ψ|−1) at the basis' centres: the rows whose displacements the compression (and a page's grid,
        :func:`defop.editor.payload.page_factors`) keeps."""
        return self.basis.delta_z(self.basis.centers.reshape(len(self.basis.centers), -1))

    def save(self, path):
        """Save to ``path`` (.npz, format ``defop-movable-1``, placement regions included): :func:`save_movable`."""
        save_movable(self, path)

    @classmethod
    def load(cls, path):
        """Load a file written by :meth:`save`, checked before any work (:func:`load_movable`)."""
        return io_mod.load_movable(path, cls)


def load_movable(path, cls=None):
    """A :class:`MovableOp` (or ``cls``) from a file of :func:`save_movable`
    (:func:`defop.operator.io.load_movable`: checked before any work, errors naming the file)."""
    return io_mod.load_movable(path, cls or MovableOp)
