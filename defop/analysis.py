"""Error metrics of a trained DefOp against the variational ground truth (Fig. 8), its timings (Table 1), and the
distortion of a deformation at its handles (the cusps of Fig. 6)."""

from __future__ import annotations

import time

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


def fit_timing(shape, samples, X, basis, spatial="hat", k=100, repeats=5):
    """Seconds of the least-squares fit (problem 8) alone, over ``repeats`` refits, BLAS on one thread.

    Table 1's LS column. Φ is built once, outside the timed region, as :func:`defop.fit.fit` does.

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
    timing : dict
        ``median`` and ``best`` seconds (noise, such as a busy BLAS thread on a shared machine, only ever
        adds time: the best is what the fit costs), and ``repeats``.
    """
    from threadpoolctl import threadpool_limits

    from . import fit as fit_mod
    from . import spatial as spatial_mod

    if X is None:
        raise ValueError("fit_time needs the ground truths X (train with a ground-truth cache, or solve them)")
    phi = spatial_mod.make_spatial(shape.mesh, spatial, k)
    with threadpool_limits(limits=1):
        times = [
            fit_mod.fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, phi).fit_time
            for _ in range(max(1, int(repeats)))
        ]
    return {"median": float(np.median(times)), "best": float(np.min(times)), "repeats": len(times)}


def fit_time(shape, samples, X, basis, spatial="hat", k=100, repeats=5):
    """The best of :func:`fit_timing`'s refits, in seconds (single-threaded BLAS).

    Returns
    -------
    seconds : float
    """
    return fit_timing(shape, samples, X, basis, spatial, k, repeats)["best"]


def repeat_timing(f, repeats=7, min_time=0.05):
    """Seconds per call of ``f()``: the median and the best of ``repeats`` timed runs, BLAS on one thread.

    Each run calls ``f`` enough times to last about ``min_time`` (calibrated once), so a run is long
    against the clock's resolution. The best is what the hardware can do (noise only ever adds time, as
    ``timeit`` says); the median shows what a user sees on a busy machine. BLAS is pinned to one thread
    with threadpoolctl for the whole measurement (the paper's FPS are single-threaded).

    Parameters
    ----------
    f : callable
        Called with no arguments.
    repeats : int
    min_time : float
        Target seconds per run.

    Returns
    -------
    timing : dict
        ``median`` and ``best`` seconds per call, ``repeats``, ``calls`` per run.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        f()  # warm-up: lazy copies, caches
        t0 = time.perf_counter()
        f()
        once = max(time.perf_counter() - t0, 1e-7)
        calls = max(1, int(min_time / once))
        runs = []
        for _ in range(max(1, int(repeats))):
            t0 = time.perf_counter()
            for _ in range(calls):
                f()
            runs.append((time.perf_counter() - t0) / calls)
    return {"median": float(np.median(runs)), "best": float(np.min(runs)), "repeats": len(runs), "calls": calls}


def frame_rate(defop, samples, repeats=15, min_time=0.02):
    """Single-thread frames per second of ``defop.evaluate_fast`` over ``samples`` (Table 1's FPS).

    Many short runs: on a shared machine a short run is more likely to go unpreempted, so the best is
    closer to what the hardware does.

    Parameters
    ----------
    defop : defop.operator.DefOp
        Exact (float32 W_F) or compressed: the guarantees of Prop. 2 and (8b) hold on either.
    samples : (k,n,2) numpy array
        Configurations cycled through, one per frame.

    Returns
    -------
    fps : dict
        ``median`` and ``best`` frames per second (from :func:`repeat_timing`), ``rank`` (None for the
        exact W_F) and ``dtype`` of the matrices a frame streams.
    """
    samples = np.asarray(samples, float)
    state = {"i": 0}

    def frame():
        defop.evaluate_fast(samples[state["i"] % len(samples)])
        state["i"] += 1

    t = repeat_timing(frame, repeats, min_time)
    dtype = str(defop.factors[1].dtype) if defop.factors is not None else "float32"
    return {"median": 1.0 / t["median"], "best": 1.0 / t["best"], "rank": defop.rank, "dtype": dtype}


def batch_frame_rate(defop, samples, k=256, repeats=5, min_time=0.2):
    """Frames per second of ``defop.evaluate_batch`` on k configurations at once (one matrix product),
    into a reused output array, BLAS on one thread.

    Returns
    -------
    fps : dict
        ``median`` and ``best`` frames per second, and ``k``.
    """
    samples = np.asarray(samples, float)
    Qs = samples[np.arange(k) % len(samples)]
    out = np.empty((k, defop.n_vertices, 2))  # reused, as an animation loop would
    t = repeat_timing(lambda: defop.evaluate_batch(Qs, out=out), repeats, min_time)
    return {"median": k / t["median"], "best": k / t["best"], "k": k}


def copy_bandwidth(nbytes=256 * 2**20, repeats=5):
    """Memory bandwidth of one thread, from a large numpy copy: bytes read + written per second (best run).

    Returns
    -------
    bandwidth : float
        Bytes per second.
    """
    src = np.ones(nbytes // 8)
    dst = np.empty_like(src)
    t = repeat_timing(lambda: np.copyto(dst, src), repeats, min_time=0.0)
    return 2.0 * nbytes / t["best"]


def frame_floor(defop, bandwidth, psi_seconds):
    """Lower bound on one frame's time: the bytes of the matrices it streams over ``bandwidth``, plus ψ.

    Returns
    -------
    seconds : float
    """
    return defop.factor_bytes(fast=True) / bandwidth + psi_seconds


def corner_angles(V, F):
    """Signed interior angle at each corner of each triangle, in radians.

    Parameters
    ----------
    V : (n,2) numpy array
    F : (m,3) int numpy array

    Returns
    -------
    angles : (m,3) numpy array
        ``angles[t, k]`` at vertex ``F[t, k]``; all three are negative on a triangle that is flipped
        (negatively oriented), so a fold shows as an angle change of more than the rest angle.
    """
    P = np.asarray(V, float)[np.asarray(F)]
    a, b = np.roll(P, -1, axis=1) - P, np.roll(P, 1, axis=1) - P  # the two edges leaving each corner
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return np.arctan2(cross, np.sum(a * b, axis=-1))


def one_rings(F, vertices):
    """Triangles incident to each vertex.

    Parameters
    ----------
    F : (m,3) int numpy array
    vertices : (h,) int numpy array

    Returns
    -------
    rings : list of h int numpy arrays
        Triangle indices around each vertex.
    """
    F = np.asarray(F)
    return [np.flatnonzero((F == v).any(axis=1)) for v in np.asarray(vertices, int)]


def handle_distortion(mesh, X, vertices):
    """Distortion in the one-ring of each handle: how sharp a cusp the deformation X makes there (Fig. 6).

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    X : (n,2) numpy array
        Deformed vertex positions.
    vertices : (h,) int numpy array
        Handle vertices (or an (n,) boolean mask, as :func:`defop.solve.check_handles` accepts).

    Returns
    -------
    distortion : dict of (h,) numpy arrays
        ``angle``: the largest change of a corner angle (degrees) over the one-ring, signed angles (a flipped
        triangle changes each angle by more than its rest value); ``conformal``: the largest Σ/σ (+inf on a
        flipped or collapsed triangle); ``flipped``: flipped or collapsed triangles in the one-ring.

    Raises
    ------
    ValueError
        X of the wrong shape or not finite; handle vertices empty, non-integer or out of range.
    """
    from .solve import check_handles  # a layer below analysis

    X = np.asarray(X, float)
    if X.shape != mesh.V.shape:
        raise ValueError(f"X must have shape {mesh.V.shape}, got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError(f"X has NaN or infinite entries (vertex {int(np.flatnonzero(~np.isfinite(X).all(1))[0])})")
    vertices = check_handles(mesh, vertices)
    change = np.degrees(np.abs(corner_angles(X, mesh.F) - corner_angles(mesh.V, mesh.F))).max(axis=1)
    from .energies import svd_frame  # a layer below analysis

    S = svd_frame(mesh.jacobians(X))[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(S[:, 1] > 0, S[:, 0] / S[:, 1], np.inf)
    folded = S[:, 1] <= 0
    rings = one_rings(mesh.F, vertices)
    return {
        "angle": np.array([change[r].max() for r in rings]),
        "conformal": np.array([K[r].max() for r in rings]),
        "flipped": np.array([int(folded[r].sum()) for r in rings]),
    }


def deformation_summary(mesh, X, vertices, expand=1.1):
    """What Fig. 6 compares between energies: folds, cusps at the handles, and scaling.

    Parameters
    ----------
    mesh : defop.mesh.Mesh
    X : (n,2) numpy array
    vertices : (h,) int numpy array
        The moving handles.
    expand : float
        A triangle counts as scaled up when both singular values exceed it (grown in every direction).

    Returns
    -------
    summary : dict
        ``flips`` (flipped or collapsed triangles), ``flips_at_handles`` (those in a handle's one-ring),
        ``handle_angle`` (the largest corner-angle change in any handle's one-ring, degrees, see
        :func:`handle_distortion`), ``area_change`` (total signed area / rest area − 1), ``scaled`` (area fraction
        of triangles scaled up by more than ``expand`` in every direction, σ > expand), ``median_conformal``
        (area-weighted median of Σ/|σ| over the mesh: 1 for a map that only rotates and scales).
    """
    from .energies import svd_frame
    from .mesh import signed_areas

    d = handle_distortion(mesh, X, vertices)
    S = svd_frame(mesh.jacobians(X))[0]
    A = mesh.areas
    w = A / A.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(S[:, 1] != 0, S[:, 0] / np.abs(S[:, 1]), np.inf)  # a triangle collapsed to a point: inf, not 0/0
    order = np.argsort(K)
    median = float(K[order][np.searchsorted(np.cumsum(w[order]), 0.5)])
    return {
        "flips": int(np.count_nonzero(S[:, 1] <= 0)),
        "flips_at_handles": int(d["flipped"].sum()),
        "handle_angle": float(d["angle"].max()),
        "area_change": float(signed_areas(X, mesh.F).sum() / A.sum() - 1),
        "scaled": float(w @ (S[:, 1] > expand)),
        "median_conformal": median,
    }
