"""Compression of a DefOp: W_F ≈ A B on the leading mass-weighted principal directions (module docstring of
:mod:`defop.operator.defop`, (★)).

B spans the leading mass-weighted principal directions of the training displacements δψ(Q_k) W_F
(Y = S W_F M^{1/2} ≈ U Σ V_rᵀ; B = V_rᵀ M^{−1/2}, A = W_F M^{1/2} V_r), so the truncation is the best rank-r
one in the (8a) norm of Appendix A on the training set. Without training samples, Y = W_F M^{1/2}. M is the
mesh's lumped mass matrix (areas in 2D, volumes in 3D), repeated over the d coordinates of each vertex. B is
zero on the handle columns and A multiplies δψ(Q), which is zero at Q = P: neither Prop. 2 nor (8b) depends on
the rank or on the precision.
"""

from __future__ import annotations

import numbers

import numpy as np

#: the default tolerance: the discarded part of the training displacements Y, relative to ‖Y‖_F. On the aleph
#: TPS-500 it keeps rank 30 and adds 0.057% to the (8a) error over 100 held-out S-ARAP samples (the target allows
#: 1%), with no flipped triangle (``benchmarks/bench_operator.py``); 1e-3 (rank 49, +0.001%) costs 1.4x the single frame
#: time (``benchmarks/bench_frame.py``); ranks 20-27 flip triangles.
TOL = 5e-3


def check_options(rank, tol, dtype):
    """Validate :func:`factorise`'s options; returns the numpy dtype (ValueError naming the option)."""
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    if rank is not None and (isinstance(rank, bool) or not isinstance(rank, numbers.Integral) or rank < 1):
        raise ValueError(f"rank must be a positive integer, got {rank!r}")
    if rank is None and not (isinstance(tol, numbers.Real) and 0 <= tol < 1):
        raise ValueError(f"tol must be a relative tolerance in [0, 1), got {tol!r}")
    return dtype


def factorise(op, rank=None, tol=TOL, dtype=np.float32):
    """The factors (A, B) of a DefOp's compressed W_F ≈ A B (module docstring).

    Parameters
    ----------
    op : defop.operator.defop.DefOp
    rank : int, optional
        Keep this many directions (1 ≤ rank; at most the numerical rank of Y).
    tol : float
        Without ``rank``: keep the fewest directions whose discarded part of Y is at most ``tol``
        times ‖Y‖_F (relative, 0 ≤ tol < 1; default :data:`TOL`).
    dtype : numpy dtype
        float32 (a frame is a memory-bound product over B, so half the bytes is half the time; the
        rounding, ~1e-7 relative, is far below the truncation) or float64.

    Returns
    -------
    A : (|Ψ|−1, r) numpy array of ``dtype``
    B : (r, d n_vertices) numpy array of ``dtype``, zero on the handle columns

    Raises
    ------
    ValueError
        A rank that is not a positive integer, a tol outside [0, 1), or another dtype.
    """
    dtype = check_options(rank, tol, dtype)
    return free_factors(op, op.handles, training_deltas(op), rank, tol, dtype)


def training_deltas(op):
    """S: δψ of ``op``'s training samples ((m, |Ψ|−1) numpy array), the rows of Y = S W_F M^{1/2}; None with
    fewer than 2 samples (Y = W_F M^{1/2})."""
    if op.train_samples is None or len(op.train_samples) < 2:
        return None
    return op.handle_basis.delta_z(op.handle_basis.z(op.train_samples))


def free_factors(op, fixed, S, rank, tol, dtype):
    """The one compression of every operator kind: (A, B) of W_F ≈ A B on the columns of the vertices that are
    not ``fixed`` (B is zero on the ``fixed`` columns), mass-weighted (:func:`principal_factors`), in ``dtype``.

    ``op``: an operator with ``WF``, ``columns``, ``d``, ``n_vertices`` and ``mesh``; ``S`` the δψ rows of the
    training samples (None: Y = W_F M^{1/2}).
    """
    n_cols = op.d * op.n_vertices
    free = np.setdiff1d(np.arange(n_cols), op.columns(fixed))
    mass = np.repeat(op.mesh.mass_matrix.diagonal(), op.d)
    A, Bf = principal_factors(op.WF[:, free], mass[free], S, rank, tol)
    B = np.zeros((A.shape[1], n_cols))
    B[:, free] = Bf
    return np.ascontiguousarray(A, dtype=dtype), np.ascontiguousarray(B, dtype=dtype)


def principal_factors(WF, mass, S=None, rank=None, tol=TOL):
    """W_F ≈ A B projected onto the leading mass-weighted principal directions of S W_F.

    With Y = S W_F M^{1/2} ≈ U Σ V_rᵀ (right singular vectors from the small Gram matrix Y Yᵀ, then
    re-orthonormalised): A = W_F M^{1/2} V_r and B = V_rᵀ M^{−1/2}, so A B = W_F M^{1/2} V_r V_rᵀ M^{−1/2}
    and the discarded part of Y is at most ``tol`` ‖Y‖_F.

    Parameters
    ----------
    WF : (q,c) numpy array
        The free columns of W_F.
    mass : (c,) numpy array
        Lumped mass of each column's vertex.
    S : (m,q) numpy array, optional
        δψ at the training samples (default: the identity, Y = W_F M^{1/2}).
    rank : int, optional
    tol : float

    Returns
    -------
    A : (q,r) numpy array
    B : (r,c) numpy array
    """
    mh = np.sqrt(mass)
    WF = WF * mh
    Y = WF if S is None else S @ WF
    lam, U = np.linalg.eigh(Y @ Y.T)
    lam, U = np.clip(lam[::-1], 0.0, None), U[:, ::-1]
    positive = max(1, int(np.sum(lam > lam[0] * 1e-24))) if lam[0] > 0 else 1
    if rank is None:
        tail = np.sqrt(np.concatenate([np.cumsum(lam[::-1])[::-1][1:], [0.0]]))
        rank = int(np.argmax(tail <= tol * np.sqrt(lam.sum()))) + 1
    rank = min(int(rank), positive)
    Vr = (U[:, :rank] / np.sqrt(np.maximum(lam[:rank], 1e-300))).T @ Y  # (r, c), orthonormal rows
    Vr, _ = np.linalg.qr(Vr.T)  # re-orthonormalise (the Gram matrix squares the condition number)
    return WF @ Vr, Vr.T / mh
