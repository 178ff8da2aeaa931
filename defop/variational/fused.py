"""Fused numba kernels of one Newton iteration: E, ∇E and the (projected) Hessian's values, straight from X.

The numpy path (:func:`defop.variational.energies.eigensystem`, then ``ReducedProblem.grad_hess`` and
``ReducedHessian.assemble``) builds every per-element array in turn: Jacobians, signed singular values, ψ and its
σ-derivatives, the modes, W = Bᵀ modes, the element Hessians K_t = A_t W diag(λ) Wᵀ, then one ``bincount``. On
meshes of a few thousand elements that is a dozen passes over memory and about 70 numpy calls per iteration, about
three times the qdldl factorisation it feeds. Here one loop over the elements does it all, in registers, and adds
each element's kept upper-triangle entries straight into the CSC values of the fixed pattern (an element → CSC
slot map computed once, :func:`slot_map`). The line search's energies are one more loop (:func:`energies`).

The formulas are those of :mod:`defop.variational.planar` (the 2×2 closed forms: the signed SVD without
trigonometry, Eqs. 10 and 11, the smoothed S-ARAP ψ_μ, the analytic eigensystem of Smith, de Goes & Kim 2019, the
kink hold of the μ = 0 stage) written per element in the same order, so that both paths agree to round-off
(``tests/test_fused_kernel.py``: 1e-12 relative, random and near-flip deformations, held elements). The numpy path
stays the reference and covers what the kernels do not (the isometric_max / isometric_exp energies). The
assembly order of each CSC value is that of the numpy ``bincount`` (elements in order, local entries row-major).

Energy codes: :data:`CODES`. numba (BSD-2) compiles these on first use and caches them beside this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .fused_common import JIT
from .fused_planar import eigen2, flip_free_step2, jacobian2, local2, scatter2, sigma2, value2
from .fused_volumetric import eigen3, sigma3, svd3

__all__ = ["CODES", "DIMS", "energies", "flip_free_step2", "grad_hess", "scatter", "slot_map", "vertex_order"]

#: the energies with a fused kernel, and their codes
CODES = {"arap": 0, "sarap": 1, "isometric": 2}
#: the dimensions with a fused kernel
DIMS = (2, 3)


def slot_map(keep, inv, m, k):
    """Element → CSC slot map: ``slot[t, i, j]`` is the index into the CSC values of local entry (i, j), else −1.

    Parameters
    ----------
    keep : (q,) int numpy array
        Flat indices t·k² + i·k + j of the kept entries (upper triangle of the free-free block).
    inv : (q,) int numpy array
        Their CSC slots.
    m, k : int
        Elements, local dofs per element ((d + 1)·d).

    Returns
    -------
    slot : (m, k, k) int64 numpy array
    """
    slot = -np.ones(m * k * k, np.int64)
    slot[keep] = inv
    return slot.reshape(m, k, k)


def vertex_order(F):
    """(m, d+1) the local vertices of each element by increasing index: the order in which ``Mesh.jacobians``'
    sparse operator (sorted CSR columns) sums them, so that both paths form bit-identical Jacobians."""
    return np.argsort(F, axis=1, kind="stable")


@njit(**JIT)
def _jacobian(X, F, D, order, t, d, J):
    """J[a, b] = Σ_i X[F[t, i], a] D[t, i, b] into J (d, d), summed in :func:`vertex_order`."""
    for a in range(d):
        for b in range(d):
            v = 0.0
            for ii in range(d + 1):
                i = order[t, ii]
                v += X[F[t, i], a] * D[t, i, b]
            J[a, b] = v


@njit(**JIT)
def _local(D, t, d, At, grad, modes, g, F, W):
    """Add A_t Bᵀ vec ∂ψ/∂J into g and write W[t] = Bᵀ modes (the element's local dofs × modes)."""
    nm = d * d
    for i in range(d + 1):
        vi = F[t, i]
        for a in range(d):
            s = 0.0
            for b in range(d):
                s += D[t, i, b] * grad[a * d + b]
            g[d * vi + a] += At * s
            for q in range(nm):
                w = 0.0
                for b in range(d):
                    w += D[t, i, b] * modes[a * d + b, q]
                W[t, d * i + a, q] = w


@njit(**JIT)
def _scatter_one(W, lp, slot, t, data):
    """Add the kept entries of W[t] diag(lp) W[t]ᵀ into the CSC values."""
    k, nm = W.shape[1], W.shape[2]
    for i in range(k):
        for j in range(k):
            p = slot[t, i, j]
            if p >= 0:
                v = 0.0
                for q in range(nm):
                    v += W[t, i, q] * lp[q] * W[t, j, q]
                data[p] += v


@njit(**JIT)
def scatter(W, lamA, slot, project, data):
    """``ReducedHessian.assemble``: Σ_t W_t diag(λ_t A_t) W_tᵀ (λ clamped at 0 when ``project``) into data (nnz,)."""
    nm = W.shape[2]
    lp = np.empty(nm)
    data[:] = 0.0
    for t in range(W.shape[0]):
        for q in range(nm):
            lp[q] = max(lamA[t, q], 0.0) if project else lamA[t, q]
        _scatter_one(W, lp, slot, t, data)


@njit(**JIT)
def energies(X, F, D, order, A, code, mu):
    """(E_μ, E) = Σ_t A_t (ψ_μ, ψ)(J_t) of the map X (n, d), d = 2 or 3, in one pass."""
    m, d = F.shape[0], X.shape[1]
    J, U, V, S = np.empty((d, d)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    T, d1, d2 = np.empty(3), np.empty(3), np.empty((3, 3))
    Es, Ee = 0.0, 0.0
    for t in range(m):
        if d == 2:
            jacobian2(X, F, D, order, t, J)
            s1, s2 = sigma2(J)
            smooth, exact = value2(code, s1, s2, mu)
        else:
            _jacobian(X, F, D, order, t, d, J)
            svd3(J, U, S, V)
            smooth, exact = sigma3(code, S, mu, T, d1, d2)
        Es += A[t] * smooth
        Ee += A[t] * exact
    return Es, Ee


@njit(**JIT)
def grad_hess(X, F, D, order, A, code, mu, kink, hold, project, slot, g, data, W, lamA):
    """One Newton iteration's element work: returns E; writes ∇E into g (d n,), the Hessian's CSC values into data
    (nnz,), and ``local`` = (W (m, (d+1)d, d²), A_t λ (m, d²), unclamped) of ``ReducedProblem.grad_hess``.

    X (n, d) with d = 2 or 3, F (m, d+1), D (m, d+1, d) the hat gradients, order (m, d+1) of :func:`vertex_order`,
    A (m,) areas, kink (m, 2) per element (and kink set in 3D; read when ``hold``), slot (m, (d+1)d, (d+1)d) of
    :func:`slot_map`; ``project`` clamps the element eigenvalues of the assembled values at 0.
    """
    m, d = F.shape[0], X.shape[1]
    nm = d * d
    J, U, V, S = np.empty((d, d)), np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    grad, lam, lp = np.empty(nm), np.empty(nm), np.empty(nm)
    modes, v3, m3 = np.empty((nm, nm)), np.empty((6, 3)), np.empty((5, 3, 3))
    g[:] = 0.0
    data[:] = 0.0
    E = 0.0
    for t in range(m):
        if d == 2:
            jacobian2(X, F, D, order, t, J)
            psi = eigen2(J, code, mu, kink[t, 0], hold, False, grad, lam, modes)
        else:
            _jacobian(X, F, D, order, t, d, J)
            svd3(J, U, S, V)
            psi = eigen3(U, S, V, code, mu, kink[t, 0], kink[t, 1], hold, grad, lam, modes, v3, m3)
        E += A[t] * psi
        if d == 2:
            local2(D, t, A[t], grad, modes, g, F, W)
        else:
            _local(D, t, d, A[t], grad, modes, g, F, W)
        for q in range(nm):
            lamA[t, q] = lam[q] * A[t]
            lp[q] = max(lamA[t, q], 0.0) if project else lamA[t, q]
        if d == 2:
            scatter2(W, lp, slot, t, data)
        else:
            _scatter_one(W, lp, slot, t, data)
    return E
