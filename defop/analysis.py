"""Error metrics of a trained DefOp against the variational ground truth (Fig. 8)."""

from __future__ import annotations

import numpy as np


def approximation_error(defop, samples, X_true, per_sample=False):
    """The paper's Fig. 8 metric: (8a) on test samples divided by the number of vertices.

    E = (1 / n_vertices) Σ_k ‖D^E(·, Q_k) − D(·, Q_k)‖²_{L²(Ω)}, the L² norm with the lumped mass
    matrix (Appendix A).

    Parameters
    ----------
    defop : defop.operator.DefOp
    samples : (k,n,2) numpy array
        Held-out handle configurations Q_k.
    X_true : (k,n_vertices,2) numpy array
        Their ground-truth deformations.
    per_sample : bool
        Also return the per-sample terms.

    Returns
    -------
    error : float
    terms : (k,) numpy array, only with ``per_sample``
    """
    samples = np.asarray(samples, float)
    X_true = np.asarray(X_true, float)
    if X_true.shape != (len(samples), defop.n_vertices, 2):
        raise ValueError(f"X_true must have shape ({len(samples)}, {defop.n_vertices}, 2), got {X_true.shape}")
    D = defop(samples)
    m = defop.mesh.mass_matrix.diagonal()
    terms = np.einsum("v,kvc->k", m, (D - X_true) ** 2)
    err = float(terms.sum() / defop.n_vertices)
    return (err, terms / defop.n_vertices) if per_sample else err


def relative_rms_error(defop, samples, X_true):
    """RMS vertex error of D against the ground truth, relative to the bounding-box diagonal.

    Returns
    -------
    rms : float
    """
    D = defop(np.asarray(samples, float))
    return float(np.sqrt(np.mean(np.sum((D - X_true) ** 2, axis=-1))) / defop.mesh.bbox_diagonal)


def flips(defop, samples):
    """Flipped triangles of D(·, Q_k) per sample.

    Returns
    -------
    counts : (k,) int numpy array
    """
    D = defop(np.asarray(samples, float))
    return np.array([int(np.count_nonzero(defop.mesh.flipped(X))) for X in D])


def fit_time(shape, samples, X, basis, spatial="hat", k=100, repeats=5):
    """Seconds of the least-squares fit (problem 8) alone: the fastest of ``repeats`` refits (Table 1's LS).

    As ``timeit`` does, the minimum: noise (allocation, page faults, a busy BLAS thread on a shared
    machine) only ever adds time. Φ is built once, outside the timed region, as :func:`defop.fit.fit` does.

    Parameters
    ----------
    shape : defop.shapes.Shape
    samples : (m,n,2) numpy array
    X : (m,n_vertices,2) numpy array
        Their ground truths.
    basis, spatial : str
    k : int
    repeats : int

    Returns
    -------
    seconds : float
    """
    from . import fit as fit_mod
    from . import spatial as spatial_mod

    if X is None:
        raise ValueError("fit_time needs the ground truths X (train with a ground-truth cache, or solve them)")
    phi = spatial_mod.make_spatial(shape.mesh, spatial, k)
    times = [
        fit_mod.fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, phi).fit_time
        for _ in range(max(1, int(repeats)))
    ]
    return float(np.min(times))
