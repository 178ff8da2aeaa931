"""The trained deformation operator DefOp: D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3).

After fitting, the spatial basis is folded into the coefficients: D(·, Q) as row-major vertex positions
is ``Ψ(Q) @ W`` with W (|Ψ| × d·n_vertices), d = 2 (triangles) or 3 (tetrahedra), read from the mesh's V.
Every evaluation path (exact, float32, compressed; one frame or a batch) uses the same form, which keeps the
paper's two guarantees by construction:

    D(·, Q) = x + δψ(Q) W_F + δψ(Q) W_H,        δψ(Q) = Ψ(Q)[1:] − Ψ(P)[1:]            (★)

* x are the rest positions, and (8b) ψ(P)ᵀ W = x makes (★) equal to Ψ(Q) W (the constant function
  drops out of the difference). At Q = P, δψ is computed from the same bits as Ψ(P) and is exactly
  zero, so D(·, P) = x holds to the last bit on every path, whatever precision or rank W_F is stored in.
* W_H are the columns of the handle vertices. Prop. 2 / (8c) fix them to the coefficients of the handles'
  own linear motion (the first 1 + dn functions of Ψ are 1 and z = (Q − P)/scale), so δψ(Q) W_H =
  scale·z = Q − P for a moving handle and 0 for a fixed one. This part is evaluated in float64 from z,
  never compressed: the handles are interpolated to round-off at every Q where Ψ(Q) is finite.
* W_F are the other columns, zero on the handles. Only W_F is stored in float32 or compressed. The
  compressed form is W_F ≈ A B with B's rows spanning the leading principal directions of the training
  displacements, mass-weighted: with S = δψ(Q_k) over the training samples, Y = S W_F M^{1/2} ≈ U Σ V_rᵀ,
  B = V_rᵀ M^{−1/2} and A = W_F M^{1/2} V_r. This is the rank-r projection that is optimal for the
  (8a) norm of Appendix A on the training set (the TPS operator reproduces it, Prop. 1); B is zero on
  the handle columns and A multiplies δψ, so neither guarantee depends on the truncation
  (:mod:`defop.operator.compress`).

The fast paths (:meth:`DefOp.evaluate_fast`, :meth:`DefOp.evaluate_batch`) multiply the basis' raw values
(:meth:`HandleBasis.delta_raw`: Q − P and, for TPS, ℓ − ℓ(0) with ℓ = r² log r², or r³ in 3D) by diag(raw_scale) W_F or
diag(raw_scale) A, folded once. A batch is one gemm for the distances, four ufuncs and one product per matrix;
a single frame (``evaluate_fast``, and ``op(Q)`` of a compressed operator) is one compiled call of
:mod:`defop.operator.kernels` (ψ, the products, x and the handles fused). They are taken while |Q − P|² < R²
(every float32 product provably finite); beyond, or at NaN, a frame takes the checked path, which raises a clear
ValueError where Ψ(Q) is not finite.

Files: :meth:`DefOp.save` and :meth:`DefOp.load` (:mod:`defop.operator.io`: format, limits, old files).
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from . import compress as compress_mod
from . import core
from . import io as io_mod
from .core import (  # noqa: F401  (public names of this module)
    EXTRAPOLATION_FACTOR,
    ExtrapolationWarning,
    FastState,
    OperatorCore,
    fast_matrices,
    training_reach,
)


class DefOp(OperatorCore):
    """A trained closed-form deformation operator, evaluated as (★) in the module docstring.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        Triangles (V (n_vertices, 2)) or tetrahedra (V (n_vertices, 3)); d is read from V.
    handles : (h,) int numpy array
        Vertex indices of all handles.
    moving : (h,) bool numpy array
    handle_basis : defop.operator.handle_bases.HandleBasis
        Ψ, a function of the moving handles (n_moving, d).
    W : (|Ψ|, d n_vertices) numpy array
        Folded coefficients: D(·, Q).ravel() = Ψ(Q) @ W.
    meta : dict, optional
        Shape, energy, bases, number of samples, library version.
    train_samples : (m,n_moving,d) numpy array, optional
        The training configurations (for the extrapolation warning and :meth:`compress`).

    Attributes
    ----------
    P : (n_moving,d) numpy array
        Rest positions of the moving handles.
    d : int
        Dimension (2 or 3).
    factors : tuple of (|Ψ|−1,r) and (r,d n_vertices) numpy arrays, or None
        A and B of the compressed W_F ≈ A B (after :meth:`compress`).
    """

    # evaluate_batch's chunk of rows when the fast matrices are small (B and the chunk's temporaries stay in cache:
    # 1.1-1.9x faster than one product at k = 256 on the aleph); a large float32 W_F is streamed once per batch
    BATCH_CHUNK = 64
    BATCH_CHUNK_BYTES = 4 * 2**20

    def __init__(self, mesh, handles, moving, handle_basis, W, meta=None, train_samples=None):
        d = int(np.shape(mesh.V)[1])
        if handle_basis.P.shape[1] != d:
            raise ValueError(f"the handle basis is in {handle_basis.P.shape[1]}D, the mesh in {d}D")
        self.setup_core(mesh, handles, moving, W, meta)
        self.handle_basis = handle_basis
        self.train_samples = None if train_samples is None else np.asarray(train_samples, float)
        self._reach = training_reach(self.P, self.train_samples)  # (n,) or None
        self._far2 = core.far_bound(self._reach)  # per handle: |Q_j − P_j|² below this is not beyond the reach
        self.fit_time = self.fold_time = None
        # (★): x, the moving handles' coordinate columns, and W_F = W[1:] without the handle columns
        self._hcols = self.columns(self.handles[self.moving])
        self._all_hcols = self.columns(self.handles)
        self.set_free_part(self.handles)
        self._work = None  # workspace of the batch product
        self._q = handle_basis.size - 1  # length of δψ

    # ------------------------------------------------------------------ properties
    @property
    def P(self):
        """(n_moving,d) rest positions of the moving handles."""
        return self.handle_basis.P

    @property
    def energy(self):
        return self.meta.get("energy")

    @property
    def n_samples(self):
        return self.meta.get("n_samples")

    def factor_bytes(self, fast=True):
        """Bytes of the matrices one evaluation streams (the memory-bandwidth floor of a frame)."""
        if self.factors is not None:
            return int(sum(f.nbytes for f in self.factors))
        return int(self._WF.size * (4 if fast else 8))

    def __repr__(self):
        comp = f", rank {self.rank} {self.factors[1].dtype}" if self.factors is not None else ""
        return (
            f"DefOp({self.meta.get('shape', '?')}, {self.meta.get('energy', '?')}, Ψ={self.handle_basis.kind} "
            f"|Ψ|={self.handle_basis.size}, Φ={self.meta.get('spatial', '?')}, "
            f"{self.n_samples} samples{comp})"
        )

    # ------------------------------------------------------------------ evaluation
    def psi(self, Q):
        """Ψ(Q): (|Ψ|,) or (k,|Ψ|) for Q (n_moving,d) or (k,n_moving,d)."""
        return self.handle_basis(Q)

    def make_fast_state(self):
        """The fast paths' :class:`FastState` (:func:`fast_matrices`, :func:`core.kernel_args`); ``extra["xh"]``:
        the moving handles' rest coordinates."""
        f = fast_matrices(self.handle_basis, self._WF, self.factors)
        f.extra["xh"] = self._x[self._hcols].copy()
        f.kernel = core.kernel_args(self.handle_basis, f.mats, self._far2)
        return f

    def _frame(self, Q, warn):
        """(★) of one float64 Q (n_moving,d) by the compiled kernel (:mod:`defop.operator.kernels`), or None
        when |Q − P|² is not below the overflow guard (NaN, inf, far); ``warn``: the extrapolation check."""
        f = self._fast if self._fast is not None and self._fast.key is self.factors else self.fast_state()
        k = f.kernel
        if k.tps is not None:  # TPS: everything in one call, dz and the guard included
            X, far = k.lib.tps_frame(Q, self.P, f.R2, k.far2, *k.tps, k.A, k.B, self._x, self._hcols, f.extra["xh"])
            if not X.size:
                return None
        else:
            dz = (Q - self.P).ravel()
            zz = np.vdot(dz, dz)  # vdot: inf for a far Q without np.dot's overflow RuntimeWarning
            if type(zz) is not np.float64 or not zz < f.R2:
                return None
            far = k.far2.size > 0 and k.lib.beyond_bound(dz, self.d, k.far2)
            y = self.handle_basis.delta_raw(dz, zz, np.empty(self._q, f.dtype))
            X = k.lib.frame_from_raw(y, k.A, k.B, self._x, self._hcols, f.extra["xh"], dz)
        if warn and far:
            check_extrapolation(self, Q)  # the full check decides (and words the warning)
        return X.reshape(-1, self.d)

    def check_mesh(self, mesh):
        """Raise ValueError unless ``mesh`` is the mesh this operator was trained on (dimension, sizes, arrays)."""
        check_mesh(self, mesh)

    def __call__(self, Q):
        """D(·, Q): the deformed vertex positions, (★) with float64 W or the compressed factors.

        Parameters
        ----------
        Q : (n_moving,d) or (k,n_moving,d) numpy array
            Positions of the moving handles; k = 0 (an empty batch) gives an empty result.

        Returns
        -------
        X : (n_vertices,d) or (k,n_vertices,d) numpy array

        Raises
        ------
        ValueError
            Q with the wrong shape or NaN, or Q so far away that Ψ(Q) is not finite (the message names Q).

        Notes
        -----
        A compressed operator evaluates one float64 Q (n_moving,d) within the overflow guard by the
        single-frame kernel of :meth:`evaluate_fast` (the same (★), validated: every other Q takes the
        checked path).
        """
        if self.factors is not None and core.fast_input(Q, self.P.shape):
            X = self._frame(Q, warn=True)
            if X is not None:
                return X
        return checked_frames(self, Q, fast=False)

    def evaluate_batch(self, Qs, out=None):
        """D(·, Q_k) for k configurations as one matrix product (trajectories, animation).

        As :meth:`evaluate_fast`: float32 W_F (or the factors) and the float64 exact part of (★), ψ
        vectorised over the rows; with small matrices (compressed) in chunks of ``BATCH_CHUNK`` rows. The
        product goes through a workspace kept on the operator: use one operator per thread.

        Parameters
        ----------
        Qs : (k,n_moving,d) numpy array
            k = 0 gives an empty (0, n_vertices, d) result.
        out : (k,n_vertices,d) float64 numpy array, optional
            Written in place and returned (an animation loop reuses it: no fresh pages per batch).

        Returns
        -------
        X : (k,n_vertices,d) numpy array
        """
        Qs = opt.real_array("Qs", Qs)  # complex, bool, strings, objects: named, not cast
        if Qs.ndim != 3:
            raise ValueError(f"Qs must have shape (k, {self.n_moving}, {self.d}), got {Qs.shape}")
        if Qs.shape[1:] != self.P.shape:
            self.handle_basis.z(Qs)  # raises the shape error
        shape = (len(Qs), self.n_vertices, self.d)
        if out is not None and (out.shape != shape or out.dtype != np.float64 or not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float64 array of shape {shape}")
        if len(Qs) == 0:  # no frame: an empty batch, like numpy
            return np.empty(shape) if out is None else out
        flat = np.empty((len(Qs), self.d * self.n_vertices)) if out is None else out.reshape(len(Qs), -1)
        if not batch_fast(self, Qs, flat):  # NaN, or a row far enough to overflow float32: the checked path
            checked_frames(self, Qs, fast=True, out=flat)
        return flat.reshape(shape) if out is None else out

    def evaluate_fast(self, Q):
        """D(·, Q) for one configuration, the interactive path: (★) with float32 W_F or the factors.

        Q must have the shape of P (a cheap check; no copy). A frame is one compiled call
        (:mod:`defop.operator.kernels`): the basis' raw values (:meth:`HandleBasis.delta_raw`) times the
        matrices of :func:`fast_matrices`, x added in float64 and Q − P written at the handles. Q with
        NaN/inf, complex, or |Q − P|² beyond the overflow guard takes the checked path (:meth:`__call__`'s
        validation: a clear ValueError where Ψ(Q) is not finite). The
        float32 W_F rounds the free vertices by about 1e-6 of the bounding-box diagonal (aleph TPS-500);
        the handles and the rest pose stay exact.

        Parameters
        ----------
        Q : (n_moving,d) numpy array

        Returns
        -------
        X : (n_vertices,d) numpy array
        """
        if np.shape(Q) != self.handle_basis.P.shape:  # broadcasting would move every handle to one point
            raise ValueError(f"Q must have shape {self.handle_basis.P.shape} (the moving handles), got {np.shape(Q)}")
        X = self._frame(Q, warn=False) if core.fast_input(Q, self.handle_basis.P.shape) else None
        return checked_frames(self, Q, fast=True) if X is None else X  # NaN, inf, complex, far: the checked path

    # ------------------------------------------------------------------ compression
    def compress(self, rank=None, tol=compress_mod.TOL, dtype=np.float32):
        """Replace W_F by a rank-r factor W_F ≈ A B (the guarantees stay exact) and return ``self``: ``rank``, or
        the fewest directions whose discarded part is at most ``tol`` (relative, in [0, 1); default 5e-3); ``dtype``
        float32 or float64. :func:`compress.factorise` raises a ValueError naming a bad option."""
        return self.set_factors(self.factorise(rank, tol, dtype))

    def factorise(self, rank=None, tol=compress_mod.TOL, dtype=np.float32):
        """The factors (A, B) :meth:`compress` would set (:func:`compress.factorise`); ``self`` is unchanged."""
        return compress_mod.factorise(self, rank, tol, dtype)

    def compression_samples(self):
        """δψ at the training samples ((m, |Ψ|−1) or None): the rows the compression and a page's grid keep."""
        return compress_mod.training_deltas(self)

    # ------------------------------------------------------------------ checks and files
    def save(self, path):
        """Save to ``path`` (str or pathlib.Path) as .npz: :func:`defop.operator.io.save` (atomic, exact round trip)."""
        io_mod.save(self, path)

    @classmethod
    def load(cls, path):
        """Load an operator written by :meth:`save` (or by an older defop), checked before any work: a missing,
        corrupt, truncated, oversized or incompatible file raises a ValueError naming the file and what is wrong
        (:func:`defop.operator.io.load`)."""
        return io_mod.load(path, cls)


def checked_frames(op, Q, fast, out=None):
    """(★) for Q (n,d) or (k,n,d), validated (the checked path of every evaluation); ``fast``: the fast paths'
    matrices (:func:`free_part`); ``out`` (k, d n_vertices) float64 receives the result."""
    Q = opt.real_array("Q", Q)  # complex, bool, strings, objects: named, not cast
    z = op.handle_basis.z(Q)  # validates shape and NaN
    Q2 = Q.reshape(-1, op.n_moving, op.d)
    with np.errstate(over="ignore", invalid="ignore"):  # a far Q: the clear error below, not numpy's warning
        dpsi = op.handle_basis.delta_z(np.atleast_2d(z))
    core.check_finite(dpsi, Q2, op.P, op.handle_basis, op.mesh)
    check_extrapolation(op, Q)
    out = free_part(op, dpsi, fast, out)
    out[:, op._hcols] += (Q2 - op.P).reshape(len(Q2), op._hcols.size)  # δψ W_H = Q − P (Prop. 2)
    big = np.abs(dpsi).max(axis=1, initial=0.0) > 1e280  # only rows this far from rest can overflow
    if big.any() and not np.isfinite(out[big]).all():
        raise not_finite_error(op, Q2[big], "D(·, Q)")
    return out.reshape(*Q.shape[:-2], op.n_vertices, op.d)


def check_extrapolation(op, Q):
    """Warn (:class:`ExtrapolationWarning`) when a moving handle of Q is beyond :data:`EXTRAPOLATION_FACTOR` times
    its farthest training sample (:func:`core.beyond_reach`; pointing at the user's line)."""
    if op._reach is None:
        return
    dist = np.linalg.norm(Q - op.P, axis=-1)
    far = core.beyond_reach(dist, op._reach)
    if np.any(far):
        idx = np.argwhere(far)[0]
        j = int(idx[-1])
        warnings.warn(
            core.extrapolation_message(j, dist[tuple(idx)], op._reach[j]),
            ExtrapolationWarning,
            stacklevel=opt.user_stacklevel(),
        )


def workspace(op, rows, M):
    """The kept (≥ rows, M's columns) workspace of the last product, of M's dtype."""
    if op._work is None or op._work.shape[0] < rows or op._work.dtype != M.dtype:
        op._work = np.empty((rows, M.shape[1]), M.dtype)
    return op._work[:rows]


def free_part(op, dpsi, fast, out=None):
    """x + δψ W_F for δψ (k,|Ψ|−1), in float64: float64 W_F, or the fast paths' matrices (``fast``) by the one
    float32 rule (:func:`core.reduced_product`: only rows of far-away Q are scaled)."""
    if op.factors is None and not fast:
        return np.add(op._x, dpsi @ op._WF, out=out)
    mats = op.fast_state().mats
    # the last product goes into a kept workspace: a fresh (k, d n_vertices) temporary per call costs
    # page faults comparable to the product itself
    y = core.reduced_product(dpsi / op.handle_basis.raw_scale, mats, out=workspace(op, len(dpsi), mats[-1]))
    return np.add(op._x, y, out=out, dtype=np.float64)


def batch_fast(op, Qs, out):
    """(★) for k rows of Qs (k,n,d) into out (k, d n_vertices), when every |Q − P|² < R2 (else False).

    ψ of the k rows vectorised (:meth:`HandleBasis.delta_raw`), then one product per factor (the
    last into the kept workspace), x added in float64 and the handles' exact part written.
    """
    f = op.fast_state()
    dz = (Qs - op.P).reshape(len(Qs), -1)
    zz = np.einsum("ij,ij->i", dz, dz)
    if not np.all(zz < f.R2):
        return False
    check_extrapolation(op, Qs)
    mats = f.mats
    c = op.BATCH_CHUNK if sum(M.nbytes for M in mats) <= op.BATCH_CHUNK_BYTES else len(Qs)
    workspace(op, min(c, len(Qs)), mats[-1])
    for i in range(0, len(Qs), c):  # chunks of rows: ψ's temporaries and the product's output stay in cache
        rows = slice(i, i + c)
        y = op.handle_basis.delta_raw(dz[rows], zz[rows], np.empty((len(dz[rows]), op._q), f.dtype))
        for M in mats[:-1]:
            y = y @ M
        y = np.matmul(y, mats[-1], out=op._work[: len(y)])
        np.copyto(out[rows], y)  # cast, then x added in place: faster than a mixed float64 + float32 sum
        out[rows] += op._x
    out[:, op._hcols] = f.extra["xh"] + dz  # δψ W_H = Q − P, exactly (Prop. 2); B and W_F are 0 there
    return True


def check_mesh(op, mesh):
    """Raise ValueError unless ``mesh`` is the mesh ``op`` was trained on."""
    if np.shape(mesh.V)[1] != op.d:
        raise ValueError(f"this operator was trained on a {op.d}D mesh, not a {np.shape(mesh.V)[1]}D one")
    if mesh.n_vertices != op.mesh.n_vertices or mesh.n_faces != op.mesh.n_faces:
        raise ValueError(
            f"this operator was trained on a mesh with {op.mesh.n_vertices} vertices and {op.mesh.n_faces} "
            f"{'triangles' if op.d == 2 else 'tetrahedra'}, not {mesh.n_vertices} and {mesh.n_faces}"
        )
    if not (np.array_equal(mesh.F, op.mesh.F) and np.allclose(mesh.V, op.mesh.V, rtol=0, atol=1e-12)):
        raise ValueError("this operator was trained on a different mesh (same size, different vertices or elements)")


def not_finite_error(op, Q, what="Ψ(Q)"):
    """The ValueError of a Q (k,n,d) whose Ψ(Q) (or D(·, Q)) is not finite, naming Q (the first row)."""
    return core.not_finite_error(Q, op.P, op.handle_basis.kind, op.mesh.bbox_diagonal, what)


def kernel_state(basis, mats, far2=None):
    """The single-frame kernel's arguments (a deprecated name of :func:`defop.operator.core.kernel_args`; its
    :class:`~defop.operator.core.KernelArgs` also answers the keys of the dict this returned)."""
    warnings.warn("kernel_state is deprecated: use defop.operator.core.kernel_args", DeprecationWarning, stacklevel=2)
    return core.kernel_args(basis, mats, far2)
