"""What every closed-form operator shares: its columns, W_F, the factors, the fast state, the checks of Q, the one
float32 rule and the one extrapolation judgement.

:class:`OperatorCore` is the base of :class:`defop.operator.defop.DefOp` and
:class:`defop.operator.movable.MovableOp` (a :class:`defop.operator.branched.BranchedOperator` holds DefOps):

* W's columns are row-major vertex coordinates (:meth:`OperatorCore.columns`); W_F is W[1:] with the columns of
  the handles that never move freely zeroed (:meth:`OperatorCore.set_free_part`);
* the factors (A, B) of a compressed W_F, and :class:`FastState`, the fast paths' matrices, overflow guard and
  kernel arguments, rebuilt when the factors change (:meth:`OperatorCore.fast_state`);
* the one float32 rule (:func:`reduced_product`): rows of δψ beyond a bound are scaled into float32's range and
  back; the one overflow guard (:func:`fast_matrices`: R² below which every float32 product is finite), beyond
  which a frame takes the checked path, where a non-finite Ψ(Q) is refused (:func:`not_finite_error`);
* the one extrapolation judgement (:func:`beyond_reach`, :data:`EXTRAPOLATION_FACTOR`);
* the checks of handle vertex indices (:func:`vertex_indices`), of an empty batch (:func:`empty_frames`), of
  handle configurations (:func:`check_configurations`, and :func:`fast_input`, the part a compiled frame needs
  before its own guard), and the key under which a rest placement's checked state is kept (:func:`placement_key`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import options as opt

#: a moving handle farther from rest than this times its farthest training sample extrapolates (a warning)
EXTRAPOLATION_FACTOR = 1.5
#: bound on |δψ| of a row (in raw units) below which the float32 products of :func:`reduced_product` stay finite
#: unscaled (|B| << 1e9)
F32_SAFE = 1e28


class ExtrapolationWarning(UserWarning):
    """A handle configuration far outside the sampled region: the operator extrapolates."""


def training_reach(P, samples):
    """The reach of a trained operator: per moving handle, the distance from rest to its farthest training sample.

    The one definition: the operators warn beyond :data:`EXTRAPOLATION_FACTOR` times it (:func:`beyond_reach`),
    and the editor draws it as the sampling region when none is known.

    Parameters
    ----------
    P : (n,d) numpy array
        Rest positions of the moving handles.
    samples : (m,n,d) numpy array or None
        The training configurations Q_k.

    Returns
    -------
    reach : (n,) numpy array or None
        None without at least 2 samples.
    """
    if samples is None or len(samples) < 2:
        return None
    return np.linalg.norm(np.asarray(samples, float) - np.asarray(P, float), axis=-1).max(axis=0)


def beyond_reach(dist, reach):
    """The one extrapolation judgement: where a handle's distance from rest exceeds
    :data:`EXTRAPOLATION_FACTOR` times its reach (bool array of ``dist``'s shape; ``reach`` (n,) broadcasts)."""
    return dist > EXTRAPOLATION_FACTOR * reach + 1e-12


def far_bound(reach):
    """Per handle, the squared distance below which a handle is surely not beyond its reach (the frame's cheap
    test; the factor 1 − 1e-9 covers the rounding of the two ways of summing the squares); None without reach."""
    return None if reach is None else (EXTRAPOLATION_FACTOR * reach) ** 2 * (1.0 - 1e-9)


def extrapolation_message(j, dist, reach, rest="rest", samples="the farthest training sample"):
    """The words of the ExtrapolationWarning of handle ``j`` at ``dist`` from ``rest``."""
    return (
        f"moving handle {j} is {dist:.3g} from {rest}, beyond {EXTRAPOLATION_FACTOR:g}x {samples} ({reach:.3g}): "
        "the operator extrapolates"
    )


def vertex_indices(name, values, n_vertices):
    """``values`` as (k,) int64 vertex indices in [0, n_vertices): integral floats pass, fractions, NaN, bools and
    out-of-range indices are a ValueError naming ``name``."""
    a = np.asarray(values)
    if a.ndim != 1 or a.dtype.kind not in "iuf" or (a.dtype.kind == "f" and not np.all(a == np.round(a))):
        raise ValueError(
            f"{name} must be a 1-D array of integer vertex indices, got {a.dtype} {np.array2string(a, threshold=10)}"
        )
    idx = a.astype(np.int64)
    bad = (idx < 0) | (idx >= n_vertices)
    if bad.any():
        raise ValueError(f"{name} must be vertex indices in [0, {n_vertices}), got {idx[bad][:5].tolist()}")
    return idx


def not_finite_error(Q, P, kind, bbox_diagonal, what="Ψ(Q)"):
    """The ValueError of a Q (k,n,d) whose Ψ(Q) (or D(·, Q)) is not finite, naming Q (the first row)."""
    Q = np.asarray(Q, dtype=float).reshape(-1, *np.shape(P))
    dist = np.max(np.abs(Q - P))  # the largest coordinate offset: squaring it would overflow to inf
    return ValueError(
        f"{what} is not finite at Q = {np.array2string(Q[0], precision=4, threshold=20)}"
        f"{' (first of the batch)' if len(Q) > 1 else ''}: a handle coordinate is {dist:.3g} from rest, beyond "
        f"what the {kind} basis can evaluate in float64 (the bounding-box diagonal is {bbox_diagonal:.3g})"
    )


@dataclasses.dataclass
class KernelArgs:
    """The single-frame kernel's arguments (:func:`kernel_args`); ``lib`` the compiled kernels
    (:mod:`defop.operator.kernels`, imported with numba on the first fast frame)."""

    lib: object
    A: np.ndarray
    B: np.ndarray
    tps: tuple | None
    far2: np.ndarray

    def __getitem__(self, name):
        """``state["A"]``: the dict of earlier versions (``tps_frame``, ``apply`` and ``beyond``: the kernels)."""
        kernels = {"tps_frame": "tps_frame", "apply": "frame_from_raw", "beyond": "beyond_bound"}
        return getattr(self.lib, kernels[name]) if name in kernels else getattr(self, name)


@dataclasses.dataclass
class FastState:
    """The fast paths' state for one set of factors: ``mats`` (A',) or (A', B), the overflow guard ``R2`` on
    |Q − P|², the dtype of the frame's δψ buffer, the kernel arguments and what a kind adds (``extra``)."""

    key: object
    mats: tuple
    R2: float
    dtype: np.dtype
    kernel: KernelArgs | None = None
    extra: dict = dataclasses.field(default_factory=dict)

    def __getitem__(self, name):
        """``state["mats"]``: the mapping access of earlier versions (a field, else an ``extra`` entry)."""
        return getattr(self, name) if name in FAST_FIELDS else self.extra[name]


#: the fields of :class:`FastState` (the keys of the dict it replaces)
FAST_FIELDS = ("key", "mats", "R2", "dtype", "kernel")


def fast_matrices(basis, WF, factors=None):
    """The matrices of the fast paths and their overflow guard, as a :class:`FastState` (no kernel yet).

    ``mats``: (A',) or (A', B) with A' = diag(raw_scale) W_F in float32 (or diag(raw_scale) A in the
    factors' dtype, in column order for the gemv), so a frame multiplies the basis' raw values
    (:meth:`HandleBasis.delta_raw`) directly. ``R2``: for |Q − P|² < R2 every float32 product is finite,
    since |entries| ≤ raw_bound(R) · Π_M (largest column abs-sum of M) ≤ 1e30; beyond it (or at NaN) a
    frame takes the checked path.

    Parameters
    ----------
    basis : defop.operator.handle_bases.HandleBasis
    WF : (|Ψ|−1, d n_vertices) numpy array
        W_F, zero on the handle columns.
    factors : tuple of (|Ψ|−1,r) and (r,d n_vertices) numpy arrays, optional
        A and B of the compressed W_F ≈ A B.
    """
    scale = basis.raw_scale[:, None]
    if factors is None:
        mats = ((WF * scale).astype(np.float32),)
    else:
        A, B = factors
        mats = (np.asfortranarray((A.astype(float) * scale).astype(A.dtype)), B)  # gemv on columns: faster
    gain = float(np.prod([max(np.abs(M).sum(axis=0, dtype=float).max(initial=0.0), 1.0) for M in mats]))
    lo, hi = -30.0, 30.0  # bisection on log10 R; raw_bound grows with R
    if basis.raw_bound(10.0**lo) * gain > 1e30:
        hi = lo = -np.inf
    for _ in range(60 if np.isfinite(lo) else 0):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if basis.raw_bound(10.0**mid) * gain <= 1e30 else (lo, mid)
    return FastState(factors, mats, 10.0 ** (2 * lo), mats[0].dtype)


def kernel_args(basis, mats, far2=None):
    """The single-frame kernel's arguments for the fast matrices ``mats`` (:func:`fast_matrices`).

    ``far2`` (n_moving,): the squared distances from rest beyond which the extrapolation check runs (None: never).
    ``A`` (q, r) row-major (the kernel's δψ A' runs along rows), or (0, 0) when W_F is uncompressed; ``B``
    the last matrix; ``tps`` the TPS constants of :meth:`TPSBasis.raw_constants` with ℓ(0) from the kernel's
    own ψ (:func:`kernels.tps_rest`, so δψ(P) = 0 bit for bit), or None for the polynomial bases.
    """
    from . import kernels  # numba: compiled (or loaded from its cache) on the first fast frame

    A = np.ascontiguousarray(mats[0]) if len(mats) == 2 else np.empty((0, 0), mats[-1].dtype)
    tps = None
    if hasattr(basis, "raw_constants"):
        cm, czeps, inv_s2, log_kernel = basis.raw_constants()
        tps = (cm, czeps, inv_s2, kernels.tps_rest(cm, czeps, inv_s2, log_kernel), log_kernel)
    far2 = np.zeros(0) if far2 is None else np.ascontiguousarray(far2, dtype=float)
    return KernelArgs(kernels, A, np.ascontiguousarray(mats[-1]), tps, far2)


def reduced_product(dpsi, mats, bound=F32_SAFE, out=None):
    """δψ (k, q) in raw units times the fast matrices: the one float32 rule.

    Rows whose largest |δψ| exceeds ``bound`` are divided by it before the cast to the matrices' dtype and
    multiplied back after the products (float64), so no float32 product overflows; the other rows are cast as
    they are. ``out``: the (k, c) buffer of the last product (the matrices' dtype).

    Returns
    -------
    (k, c) numpy array: float64 where rows were scaled, else the matrices' dtype.
    """
    s = np.abs(dpsi).max(axis=1, initial=0.0)
    far = s > bound
    if far.any():
        s = np.where(far, s, 1.0)[:, None]
        dpsi = dpsi / s
    y = dpsi.astype(mats[0].dtype)
    for M in mats[:-1]:
        y = y @ M
    y = np.matmul(y, mats[-1], out=out)
    return y * s if far.any() else y


def check_finite(dpsi, Q2, P, basis, mesh):
    """Raise :func:`not_finite_error` for the rows of δψ (k, q) that are not finite (Q2 (k, n, d))."""
    finite = np.isfinite(dpsi).all(axis=1)
    if not finite.all():
        raise not_finite_error(Q2[~finite], P, basis.kind, mesh.bbox_diagonal)


def empty_frames(Q, n_vertices, d):
    """The (0, n_vertices, d) result of an empty batch Q (0, n, d), or None for any other Q."""
    return np.empty((0, n_vertices, d)) if np.ndim(Q) == 3 and len(Q) == 0 else None


class OperatorCore:
    """The state every closed-form operator shares (module docstring): set up by :meth:`setup_core`.

    Attributes
    ----------
    mesh, d, handles, moving, W, meta, factors
    """

    def setup_core(self, mesh, handles, moving, W, meta):
        """Set the shared state; ``handles`` checked as vertex indices, ``moving`` one flag per handle."""
        from .. import __version__

        self.mesh = mesh
        self.d = int(np.shape(mesh.V)[1])
        self.handles = vertex_indices("handles", handles, mesh.n_vertices)
        self.moving = np.asarray(moving, dtype=bool)
        if self.moving.shape != self.handles.shape:
            raise ValueError(f"moving must be one flag per handle ({self.handles.shape}), got {self.moving.shape}")
        self.W = np.ascontiguousarray(W, dtype=float)
        self.meta = {"version": __version__, **(meta or {})}
        self.factors = None  # (A, B) after compress()
        self._x = np.ascontiguousarray(mesh.V, dtype=float).ravel()
        self._fast = None

    def set_free_part(self, vertices):
        """W_F = W[1:] with the columns of ``vertices`` (the handles that never move freely) zeroed."""
        self._WF = self.W[1:].copy()
        self._WF[:, self.columns(vertices)] = 0.0

    def columns(self, vertices):
        """Columns of W (row-major x, y[, z] per vertex) of ``vertices`` (k,): (k d,) int array."""
        return (self.d * np.asarray(vertices, np.int64)[:, None] + np.arange(self.d)).ravel()

    @property
    def WF(self):
        """W_F: W[1:] with the fixed handle columns zeroed, (|Ψ|−1, d n_vertices) float64 (read only)."""
        return self._WF

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices

    @property
    def rank(self):
        """Rank of the compressed factor, or None when uncompressed."""
        return None if self.factors is None else self.factors[0].shape[1]

    def set_factors(self, factors):
        """Install the compressed factors (A, B) (or None) and record the rank in ``meta``. Returns ``self``."""
        self.factors = factors
        if factors is None:
            self.meta.pop("rank", None)
        else:
            self.meta["rank"] = factors[0].shape[1]
        return self

    def decompress(self):
        """Go back to the exact W_F."""
        return self.set_factors(None)

    def fast_state(self):
        """The :class:`FastState` of the current factors (the kind's ``make_fast_state()``, made on first use and
        rebuilt when the factors change)."""
        f = self._fast
        if f is None or f.key is not self.factors:
            f = self._fast = self.make_fast_state()
        return f


def fast_input(Q, shape):
    """Whether Q may enter a compiled frame unchecked: a float64 numpy array of exactly ``shape``.

    The rest of :func:`check_configurations` is the kernel's: its overflow guard (|Q − P|² below R2, false at NaN
    and inf) sends any other Q to the checked path, where the full check raises its ValueError, and its reach
    bound (:func:`far_bound`) to the full extrapolation check.
    """
    return type(Q) is np.ndarray and Q.dtype == np.float64 and Q.shape == shape


def placement_key(P):
    """A hashable key of a rest placement P as given, under which its checked and resolved state may be kept:
    ``()`` for None, (dtype, shape, bytes) for a numpy array of integers or floats (equal keys: the same P bit
    for bit, hence the same resolution), None for anything else (checked every time)."""
    if P is None:
        return ()
    if type(P) is np.ndarray and P.dtype.kind in "iuf":
        return (P.dtype.str, P.shape, P.tobytes())
    return None


class KeptPlacements:
    """The checked and resolved states of the last ``limit`` rest placements, for one set of factors: kept under
    P as given (:func:`placement_key`) and under its vertices, all dropped when the factors change."""

    def __init__(self, limit=32):
        self.limit, self.factors, self.states = int(limit), None, {}

    def get(self, P, factors, resolve, make):
        """The state of placement P for ``factors``: kept, or ``make(resolve(P))`` (``resolve`` checks P and
        returns its vertices idx, ``make`` the state of idx), then kept under P and idx, the oldest keys dropped."""
        if self.factors is not factors:
            self.states, self.factors = {}, factors
        key = placement_key(P)
        st = self.states.get(key) if key is not None else None
        if st is None:
            idx = resolve(P)
            kidx = placement_key(idx)
            st = self.states.get(kidx) or make(idx)
            for k in (key, kidx):
                if k is not None:
                    self.states[k] = st
            while len(self.states) > self.limit:
                del self.states[next(iter(self.states))]
        return st


def check_configurations(Q, n, d=2):
    """The one check of handle configurations: Q (n, d) or (k, n, d), real and finite, as a float array
    (a ValueError naming Q and the condition)."""
    Q = opt.real_array("Q", Q)  # complex, bool, strings, objects: named, not cast (float() drops an imaginary part)
    if Q.ndim not in (2, 3) or Q.shape[-2:] != (n, d):
        raise ValueError(f"Q must have shape ({n}, {d}) or (k, {n}, {d}) for {n} moving handles, got {Q.shape}")
    if not np.isfinite(Q).all():
        where = np.argwhere(~np.isfinite(Q))[0].tolist()
        raise ValueError(f"Q has NaN or infinite entries (first at {where}): {np.array2string(Q, threshold=20)}")
    return Q
