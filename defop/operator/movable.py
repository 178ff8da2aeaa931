"""Handles that move at rest: the operator D(x; P, Q) (§5's last open question, issue 38).

The rest positions of the *movable* handles (:mod:`defop.scene.placement`) are inputs. The operator is

    D(·; P, Q) = x + δψ(P, Q) W_F + Σ_ℓ g_{v_ℓ} r_ℓ,     δψ(P, Q) = Ψ(z(P, Q)) − Ψ(z(P, P))            (M)

* Ψ is the thin-plate spline basis (:class:`defop.operator.handle_bases.TPSBasis`, kernel r² log r in 2D) on the
  joint space z = [(P_b − P_b⁰)/s_P, (Q − P)/s_Q] ∈ R^{d(b + n)}: the b movable handles' rest offsets from
  their nominal vertices and the n moving handles' displacements. Its centres are the training pairs
  (P_k, Q_k) *and* their rest poses (P_k, P_k) (and the nominal rest), with data the displacements X_k − x and 0,
  so the interpolant f = Ψ W is 0 at every sampled rest pose and reproduces every training pair (Prop. 1).
* δψ subtracts Ψ at (P, P) from the same code on the same bits: at Q = P the two are equal and δψ = 0, so
  D(·; P, P) = x bit for bit (8b), whatever precision W_F is stored in; the rows of a batch at rest are also set
  to x explicitly (a gemm does not promise equal rows equal bits).
* r_ℓ = (q_ℓ − p_ℓ) − u(v_ℓ) is handle ℓ's residual at its vertex v_ℓ, computed in float64 from the same u the
  frame adds (float32 products are cast first), and g_v the placement's bump (1 at v, 0 at the other regions'
  vertices and at every handle that is not movable). Then the handle rows are written as q_ℓ exactly (Prop. 2,
  bit for bit), as are non-movable moving handles (q) and fixed handles (x); W_F is 0 on their columns.
* Affine precision: a displacement field affine in (Q − P) with coefficients independent of P is reproduced
  (the affine part of Ψ); the P-affine part cancels in δψ. Elsewhere between samples D interpolates.

Batch semantics: one P per call; Q (n, d) or a batch (k, n, d) at that P. P is given for the movable handles
only: (b,) vertex indices or (b, d) points (snapped within :data:`defop.scene.placement.SNAP_TOL` of the bbox
diagonal). Extrapolation is judged on Q − P against the training offsets Q_k − P_k. When a rest handle moves while
the shape is deformed, :func:`retarget` keeps q − p (the handle's displacement travels with it); the operator
itself is a function of (P, Q) and keeps no state.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from ..scene.placement import PlacementRegions
from . import compress as compress_mod
from . import handle_bases as hb
from . import io as io_mod
from .defop import EXTRAPOLATION_FACTOR, ExtrapolationWarning, fast_matrices, kernel_state
from .fit import structure


def joint_z(V, nominal, idx, handles_moving, Q, s_p, s_q):
    """The joint coordinates z (k, b + n, d) of rest vertices ``idx`` (b,) and Q (k, n, d).

    ``handles_moving`` (n,) are the moving handles' vertices with the movable ones at ``idx``.
    """
    a = (V[idx] - V[nominal]) / s_p  # (b, d)
    bq = (Q - V[handles_moving]) / s_q  # (k, n, d)
    return np.concatenate([np.broadcast_to(a, (len(bq), *a.shape)), bq], axis=1)


def rest_centres(zs, b):
    """The distinct rest poses (P_k, P_k) of joint samples zs (m, b + n, d), the nominal (0) first: (r, b + n, d)."""
    z0 = zs.copy()
    z0[:, b:] = 0.0
    flat = np.unique(z0.reshape(len(z0), -1), axis=0)
    flat = flat[np.any(flat != 0.0, axis=1)]
    return np.concatenate([np.zeros((1, *zs.shape[1:])), flat.reshape(-1, *zs.shape[1:])])


def fit_movable(mesh, handles, moving, placement, idx, Q, X, meta=None, p_weight=1.0):
    """Fit (M): TPS interpolation of the displacements over the joint space.

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

    Returns
    -------
    MovableOp
    """
    idx = np.asarray(idx, np.int64)
    Q, X = np.asarray(Q, float), np.asarray(X, float)
    m, n, d = Q.shape
    if idx.shape != (m, placement.n_movable) or X.shape != (m, mesh.n_vertices, d):
        raise ValueError(f"idx must be (m, {placement.n_movable}) and X (m, {mesh.n_vertices}, {d}) for m = {m}")
    hm = np.array([placement.handles_at(i)[moving] for i in idx])  # (m, n)
    off_p = mesh.V[idx] - mesh.V[placement.nominal]
    off_q = Q - mesh.V[hm]
    s_p = (float(np.sqrt(np.mean(np.sum(off_p**2, axis=-1)))) or 1.0) / p_weight
    s_q = float(np.sqrt(np.mean(np.sum(off_q**2, axis=-1)))) or 1.0
    zs = np.concatenate([off_p / s_p, off_q / s_q], axis=1)
    rc = rest_centres(zs, placement.n_movable)
    centres = np.concatenate([rc, zs])
    Y = np.concatenate([np.zeros((len(rc), mesh.n_vertices * d)), (X - mesh.V).reshape(m, -1)])
    psi = hb.TPSBasis(np.zeros(zs.shape[1:]), centres, 1.0)
    G, _ = structure(psi, centres)
    W = G @ Y  # the rest pose's data is 0: β Y[0] drops
    meta = {**(meta or {}), "basis": "tps-joint", "n_samples": m, "n_rest_centres": len(rc)}
    return MovableOp(mesh, handles, moving, placement, psi, W, (s_p, s_q), meta, reach_of(off_q))


def reach_of(off_q):
    """Per moving handle, the farthest training offset |Q_k − P_k| (n,)."""
    return np.linalg.norm(off_q, axis=-1).max(axis=0)


def retarget(Q, placement, old, new):
    """Q after movable rest handles move from vertices ``old`` to ``new`` (b,) while deformed: q − p stays.

    Returns
    -------
    Q : (n, d) numpy array
    """
    Q = np.array(Q, float)
    Q[placement.moving_rows()] += placement.mesh.V[new] - placement.mesh.V[old]
    return Q


def correct(mesh, placement, handles, moving, st, u, Qs):
    """x + u, the residual correction Σ_ℓ g_{v_ℓ} r_ℓ in float64, the handles written exactly, rest rows = x.

    ``st``: the placement state (``idx``, ``hm``, ``P``, ``rows`` as :meth:`MovableOp.at` makes it); u (k, d n)
    float64, Qs (k, n, d). Returns (k, d n_vertices).
    """
    k, d, n_vertices = len(Qs), mesh.dim, mesh.n_vertices
    X = (mesh.V.ravel() + u).reshape(k, n_vertices, d)
    disp = Qs - st["P"]  # (k, n, d)
    r = disp[:, placement.moving_rows()] - u.reshape(k, n_vertices, d)[:, st["idx"]]  # (k, b, d)
    sup, wt = st["bumps"]
    X[:, sup] += np.matmul(wt, r)  # (s, b) @ (k, b, d): Σ_ℓ g_{v_ℓ} r_ℓ on the bumps' support
    X[:, st["hm"]] = Qs  # Prop. 2: every moving handle on its target, bit for bit
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
    r = (Q - st["P"])[:, op.placement.moving_rows()] - u.reshape(1, op.n_vertices, op.d)[:, st["idx"]]
    return float(np.abs(r).max() / op.mesh.bbox_diagonal)


class MovableOp:
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

    def __init__(self, mesh, handles, moving, placement, basis, W, scales, meta=None, reach=None):
        from .. import __version__

        self.mesh, self.placement, self.basis = mesh, placement, basis
        self.handles = np.asarray(handles, np.int64)
        self.moving = np.asarray(moving, bool)
        self.d = mesh.dim
        self.W = np.ascontiguousarray(W, float)
        self.scales = (float(scales[0]), float(scales[1]))
        self.meta = {"version": __version__, **(meta or {})}
        self.reach = None if reach is None else np.asarray(reach, float)
        self.factors = None
        self._x = np.ascontiguousarray(mesh.V, float).ravel()
        still = np.setdiff1d(np.arange(len(self.handles)), placement.movable)
        self._still = self.handles[still]  # handles that never leave their vertex
        self._WF = self.W[1:].copy()
        self._WF[:, self.columns(self._still)] = 0.0
        self._fast = None
        self._at = None  # (idx bytes, state) of the last rest placement

    def columns(self, vertices):
        """Columns (row-major x, y[, z] per vertex) of ``vertices`` (k,): (k d,) int array."""
        return (self.d * np.asarray(vertices, np.int64)[:, None] + np.arange(self.d)).ravel()

    @property
    def n_moving(self):
        return int(self.moving.sum())

    @property
    def n_vertices(self):
        return self.mesh.n_vertices

    @property
    def rank(self):
        return None if self.factors is None else self.factors[0].shape[1]

    def __repr__(self):
        comp = f", rank {self.rank}" if self.factors is not None else ""
        return (
            f"MovableOp({self.meta.get('shape', '?')}, {self.placement.n_movable} movable of {self.n_moving} "
            f"moving handles, |Ψ|={self.basis.size}, {self.meta.get('n_samples')} samples{comp})"
        )

    # ------------------------------------------------------------------ the rest placement
    def at(self, P=None):
        """The state of rest placement P (:meth:`PlacementRegions.resolve`), kept until P changes: its vertices,
        the moving handles' rest positions, z(P, P) and the kernel's frame at (P, P)."""
        last = self._at
        if (
            last is not None
            and last["key"] is self.factors
            and (
                (P is None and last["nominal"])
                or (
                    type(P) is np.ndarray
                    and P.dtype.kind in "iu"
                    and P.shape == last["idx"].shape
                    and (P == last["idx"]).all()
                )
            )
        ):
            return last  # the placement of the last frame (an interactive drag): nothing to resolve
        idx = self.placement.resolve(P)
        if self._at is not None and np.array_equal(self._at["idx"], idx) and self._at["key"] is self.factors:
            return self._at
        hm = self.placement.handles_at(idx)[self.moving]
        Pm = self.mesh.V[hm]
        z0 = joint_z(self.mesh.V, self.placement.nominal, idx, hm, Pm[None], *self.scales)[0]
        st = {
            "idx": idx,
            "key": self.factors,
            "hm": hm,
            "P": Pm,
            "z0": z0,
            "bumps": self.placement.bumps_at(idx),
            "rows": self.placement.moving_rows(),
            "fixed": self.handles[~self.moving],
            "nominal": bool(np.array_equal(idx, self.placement.nominal)),
        }
        st["psi0"] = self.basis.delta_z(z0.reshape(1, -1))  # (1, |Ψ|−1), float64
        k = self._fast_state()["kernel"]
        st["X0"] = self._kernel(z0, k)
        self._at = st
        return st

    def _fast_state(self):
        if self._fast is None or self._fast["key"] is not self.factors:
            f = fast_matrices(self.basis, self._WF, self.factors)
            f["kernel"] = kernel_state(self.basis, f["mats"], None)
            f["kernel"].update(zero=np.zeros(self.basis.P.shape), none=np.zeros(0, np.int64), nothing=np.zeros(0))
            from .movable_kernels import finish_frame  # numba: compiled (or loaded from its cache) on first use

            f["finish"] = finish_frame
            self._fast = f
        return self._fast

    def _kernel(self, z, k):
        """x + (ψ_raw(z) − ℓ(0)) A' B by the compiled frame (empty when beyond the overflow guard)."""
        return k["tps_frame"](
            z, k["zero"], self._fast["R2"], k["far2"], *k["tps"], k["A"], k["B"], self._x, k["none"], k["nothing"]
        )[0]

    # ------------------------------------------------------------------ evaluation
    def _check_Q(self, Q, st):
        if not (type(Q) is np.ndarray and Q.dtype == np.float64):
            Q = opt.real_array("Q", Q)
        n, d = self.n_moving, self.d
        if Q.ndim not in (2, 3) or Q.shape[-2:] != (n, d):
            raise ValueError(f"Q must have shape ({n}, {d}) or (k, {n}, {d}) for {n} moving handles, got {Q.shape}")
        if not np.isfinite(Q).all():
            raise ValueError(f"Q has NaN or infinite entries: {np.array2string(Q, threshold=20)}")
        if self.reach is not None:
            dist = np.sqrt(np.square(Q - st["P"]).sum(axis=-1).reshape(-1, n).max(axis=0))
            far = np.flatnonzero(dist > EXTRAPOLATION_FACTOR * self.reach + 1e-12)
            if far.size:
                j = int(far[0])
                warnings.warn(
                    f"moving handle {j} is {dist[j]:.3g} from its rest position P, beyond 1.5x the farthest "
                    f"training offset ({self.reach[j]:.3g}): the operator extrapolates",
                    ExtrapolationWarning,
                    stacklevel=3,
                )
        return Q

    def __call__(self, Q, P=None):
        """D(·; P, Q): (n_vertices, d), or (k, n_vertices, d) for a batch Q (k, n, d) at one P, in float64.

        Uncompressed: float64 W_F. Compressed: the factors (one frame by the compiled kernel).
        """
        st = self.at(P)
        Q = self._check_Q(Q, st)
        Q2 = Q.reshape(-1, self.n_moving, self.d)
        if self.factors is not None and Q.ndim == 2:
            return self._frame(Q, st)
        out = self._finish(self.displacement(Q2, st), st, Q2)
        return out.reshape(*Q.shape[:-2], self.n_vertices, self.d)

    def displacement(self, Qs, st):
        """u = δψ(P, Q_k) W_F (k, d n_vertices) in float64 (the factors' product when compressed), no correction."""
        z = joint_z(self.mesh.V, self.placement.nominal, st["idx"], st["hm"], Qs, *self.scales)
        dpsi = self.basis.delta_z(z.reshape(len(z), -1)) - st["psi0"]
        if self.factors is None:
            return dpsi @ self._WF
        return self._product(dpsi)

    def _product(self, dpsi):
        """δψ (k, |Ψ|−1) times the fast matrices (float32 W_F or the factors), cast to float64."""
        mats = self._fast_state()["mats"]
        dpsi = dpsi / self.basis.raw_scale
        s = np.maximum(np.abs(dpsi).max(axis=1, keepdims=True), 1.0)  # scaled into float32's range and back
        y = (dpsi / s).astype(mats[0].dtype)
        for M in mats:
            y = y @ M
        return y.astype(float) * s

    def _frame(self, Q, st):
        z = st["z0"].copy()  # [(P_b − P_b⁰)/s_P, 0], kept per placement; the Q part is the frame's (joint_z's sums)
        np.divide(
            np.subtract(Q, st["P"], out=z[self.placement.n_movable :]),
            self.scales[1],
            out=z[self.placement.n_movable :],
        )
        Xz = self._kernel(z, self._fast_state()["kernel"])
        if not Xz.size or not st["X0"].size:  # beyond the float32 guard: numpy with scaling
            u = self._product(self.basis.delta_z(z.reshape(1, -1)) - st["psi0"])
            return self._finish(u, st, Q[None])[0].reshape(self.n_vertices, self.d)
        sup, wt = st["bumps"]
        out = self._fast["finish"](
            Xz, st["X0"], self._x, Q, st["P"], st["idx"], st["rows"], st["hm"], sup, wt, st["fixed"]
        )
        return out.reshape(self.n_vertices, self.d)

    def evaluate_fast(self, Q, P=None):
        """One frame by the compiled kernel: float32 W_F (or the factors), the correction in float64."""
        st = self.at(P)
        Q = self._check_Q(Q, st)
        if Q.shape != st["P"].shape:
            raise ValueError(f"Q must have shape {st['P'].shape} (one frame), got {Q.shape}")
        return self._frame(Q, st)

    def evaluate_batch(self, Qs, P=None):
        """D(·; P, Q_k) for a batch Qs (k, n, d) at one P: float32 products, the correction in float64."""
        st = self.at(P)
        Qs = self._check_Q(Qs, st)
        if Qs.ndim != 3:
            raise ValueError(f"Qs must have shape (k, {self.n_moving}, {self.d}), got {Qs.shape}")
        if len(Qs) == 0:
            return np.empty((0, self.n_vertices, self.d))
        z = joint_z(self.mesh.V, self.placement.nominal, st["idx"], st["hm"], Qs, *self.scales)
        u = self._product(self.basis.delta_z(z.reshape(len(z), -1)) - st["psi0"])
        return self._finish(u, st, Qs).reshape(len(Qs), self.n_vertices, self.d)

    def _finish(self, u, st, Qs):
        return correct(self.mesh, self.placement, self.handles, self.moving, st, u, Qs)

    # ------------------------------------------------------------------ compression and files
    def compress(self, rank=None, tol=compress_mod.TOL, dtype=np.float32, samples=None):
        """W_F ≈ A B (:func:`defop.operator.compress.principal_factors`), the directions of δψ at ``samples``
        (joint z rows, (m, |Ψ|−1) δψ; default the basis' centres); the guarantees stay exact. Returns self."""
        dtype = compress_mod.check_options(rank, tol, dtype)
        free = np.setdiff1d(np.arange(self.d * self.n_vertices), self.columns(self._still))
        C = self.basis.centers.reshape(len(self.basis.centers), -1)
        S = self.basis.delta_z(C) if samples is None else samples
        mass = np.repeat(self.mesh.mass_matrix.diagonal(), self.d)
        A, Bf = compress_mod.principal_factors(self._WF[:, free], mass[free], S, rank, tol)
        B = np.zeros((A.shape[1], self.d * self.n_vertices))
        B[:, free] = Bf
        self.factors = (np.ascontiguousarray(A, dtype=dtype), np.ascontiguousarray(B, dtype=dtype))
        self.meta["rank"] = A.shape[1]
        return self

    def decompress(self):
        self.factors = None
        self.meta.pop("rank", None)
        return self

    def save(self, path):
        """Save to ``path`` (.npz, format ``defop-movable-1``, placement regions included): :func:`save_movable`."""
        save_movable(self, path)

    @classmethod
    def load(cls, path):
        """Load a file written by :meth:`save`, checked before any work (:func:`load_movable`)."""
        return load_movable(path, cls)


class CarryOp:
    """The second design of issue 38: the nominal fixed-P operator, carried with the rest handles.

    A rest-space warp w_P(x) = x + Σ_ℓ g_{v_ℓ}(x) (p_ℓ⁰ − p_ℓ) (the placement bumps) takes each movable handle's
    vertex to its nominal position; the nominal operator D⁰ is evaluated with the same handle displacements,
    Q' = Q − P + P⁰, and its displacement field is read at w_P(x) (barycentric, in the rest mesh):
    D(x; P, Q) = x + u⁰(w_P(x); Q'), then the correction of (M). No joint training: one fixed-P operator.
    (8b) holds as for (M) (u⁰ = 0 at Q' = P⁰, and rest rows are x), Prop. 2 by the exact handle rows.

    Parameters
    ----------
    op0 : defop.operator.defop.DefOp
        Trained at the nominal placement.
    placement : defop.scene.placement.PlacementRegions
    """

    def __init__(self, op0, placement):
        self.op0, self.placement, self.mesh = op0, placement, op0.mesh
        self.handles, self.moving, self.d = op0.handles, op0.moving, op0.d
        self.n_vertices, self._at = op0.n_vertices, None

    def at(self, P=None):
        import scipy.sparse as sp

        idx = self.placement.resolve(P)
        if self._at is not None and np.array_equal(self._at["idx"], idx):
            return self._at
        hm = self.placement.handles_at(idx)[self.moving]
        y = self.mesh.V.copy()
        g, rows = self.placement.g, self.placement.bump_rows(idx)
        for ell, row in enumerate(rows):
            a, b = g.indptr[row], g.indptr[row + 1]
            y[g.indices[a:b]] += g.data[a:b, None] * (self.mesh.V[self.placement.nominal[ell]] - self.mesh.V[idx[ell]])
        elem, bary = self.mesh.locate(y)
        n = self.n_vertices
        S = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(n), self.d + 1), self.mesh.F[elem].ravel())), (n, n))
        self._at = {
            "idx": idx,
            "hm": hm,
            "P": self.mesh.V[hm],
            "bumps": self.placement.bumps_at(idx),
            "S": S,
            "shift": self.op0.P - self.mesh.V[hm],
        }
        return self._at

    def __call__(self, Q, P=None, fast=False):
        """D(·; P, Q) for Q (n, d) or (k, n, d) at one P; ``fast``: the nominal operator's fast path."""
        st = self.at(P)
        Q = opt.real_array("Q", Q)
        Qs = Q.reshape(-1, *st["P"].shape)
        Qn = Qs + st["shift"]
        X0 = np.stack([self.op0.evaluate_fast(q) for q in Qn]) if fast else self.op0(Qn)
        u = np.stack([st["S"] @ (x - self.mesh.V) for x in X0]).reshape(len(Qs), -1)
        out = correct(self.mesh, self.placement, self.handles, self.moving, st, u, Qs)
        return out.reshape(*Q.shape[:-2], self.n_vertices, self.d)


# ---------------------------------------------------------------------- files
#: the movable-handle operator's file format (an .npz archive checked as every operator file, :mod:`.io`)
FORMAT = "defop-movable-1"
MEMBERS = (
    "header",
    "V",
    "F",
    "handles",
    "moving",
    "joint_W",
    "joint_centers",
    "reach",
    "placement_movable",
    "placement_vertices",
    "placement_sizes",
    "placement_reach",
    "factor_A",
    "factor_B",
)


def save_movable(op, path):
    """Write ``op`` (:class:`MovableOp`) to ``path`` atomically: arrays, placement regions, JSON header."""
    import json

    arrays = {
        "V": op.mesh.V,
        "F": op.mesh.F,
        "handles": op.handles,
        "moving": op.moving,
        "joint_W": op.W,
        "joint_centers": op.basis.centers,
        **op.placement.to_arrays(),
    }
    if op.reach is not None:
        arrays["reach"] = op.reach
    if op.factors is not None:
        arrays["factor_A"], arrays["factor_B"] = op.factors
    header = {
        "format": FORMAT,
        "format_version": 1,
        "kind": "movable",
        "dim": op.d,
        "meta": op.meta,
        "scales": list(op.scales),
    }
    arrays["header"] = np.array(json.dumps(header))
    io_mod._write(path, arrays)


def _check_declared(path, header, headers, version):
    d = io_mod._field(path, "dim", header.get("dim"))
    V = headers.get("V", (None,))[0]
    if V is not None and (len(V) != 2 or V[1] != d):
        raise io_mod.OperatorFileError(f"{path}: the header says dim = {d}, but V is {'×'.join(map(str, V))}")
    C = headers.get("joint_centers", (None,))[0]
    if C is not None and len(C) >= 1 and C[0] > io_mod.MAX_CENTERS:
        raise io_mod.OperatorFileError(f"{path} declares {C[0]} TPS centres, limit {io_mod.MAX_CENTERS}")


def load_movable(path, cls=None):
    """Read a file of :func:`save_movable`, checked before any work (:func:`defop.operator.io.load`'s steps 1-6),
    then every array against the others; a ValueError (``OperatorFileError``) names the file and the problem."""
    header, data, _ = io_mod._read(path, {FORMAT: 1}, MEMBERS, len(MEMBERS), _check_declared)
    A = io_mod._array
    try:
        V = A(data, "V", 2, "f")
        d = V.shape[1]
        mesh = Mesh(V, A(data, "F", 2, "iu", (None, d + 1)))
        handles = A(data, "handles", 1, "iu")
        moving = A(data, "moving", 1, "b", handles.shape)
        regions = {k: A(data, k, 1, "iu") for k in ("placement_movable", "placement_vertices", "placement_sizes")}
        regions["placement_reach"] = A(data, "placement_reach", 1, "f")
        pr = PlacementRegions.from_arrays(mesh, handles, moving, regions)
        C = A(data, "joint_centers", 3, "f", (None, pr.n_movable + int(moving.sum()), d))
        basis = hb.TPSBasis(np.zeros(C.shape[1:]), C, 1.0)
        W = A(data, "joint_W", 2, "f", (basis.size, d * len(V)))
        reach = A(data, "reach", 1, "f", (int(moving.sum()),)) if "reach" in data else None
        if reach is not None and np.any(reach < 0):
            raise ValueError(f"array 'reach' must be {len(reach)} non-negative finite lengths, got {reach}")
        s = [float(x) for x in header["scales"]]
        if len(s) != 2 or not all(np.isfinite(s)) or min(s) <= 0:
            raise ValueError(f"header 'scales' must be two positive numbers, got {s}")
        op = (cls or MovableOp)(mesh, handles, moving, pr, basis, W, s, header["meta"], reach)
        op.meta = header["meta"]
        if "factor_A" in data:
            fa = A(data, "factor_A", 2, "f", (basis.size - 1, None))
            fb = A(data, "factor_B", 2, "f", (fa.shape[1], d * len(V)))
            if fa.dtype != fb.dtype or np.any(fb[:, op.columns(op._still)] != 0):
                raise ValueError(
                    "factor_B must be zero on the columns of the handles that are not movable, in the dtype of factor_A"
                )
            op.factors = (fa, fb)
        return op
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, MemoryError) as exc:
        what = f"missing {exc}" if isinstance(exc, KeyError) else str(exc) or type(exc).__name__
        raise io_mod.OperatorFileError(f"{path} is not a valid movable-handle operator file: {what}") from exc
