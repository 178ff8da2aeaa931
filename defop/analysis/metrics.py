"""Error metrics of a trained DefOp against the variational ground truth (Fig. 8) and its timings (Table 1).

The error measures and their names (docs/glossary.md): "(8a)/n over N held-out samples" (:func:`approximation_error`)
and "mean (8a)/n per sample" (that divided by N).

The distortion of a deformation at its handles (the cusps of Fig. 6) is :mod:`defop.analysis.distortion`."""

from __future__ import annotations

import itertools
import time

import numpy as np

from .. import options as opt
from ..training.solves import training_cpu


def _samples(defop, samples):
    """(k,n,d) float array of configurations of the operator's n moving handles, k >= 1, finite (d = mesh.dim)."""
    samples = opt.real_array("samples", samples)
    basis = getattr(defop, "handle_basis", None)  # None: frames computed elsewhere (defop.analysis.compare)
    n = len(basis.P) if basis is not None else samples.shape[1] if samples.ndim == 3 else "n"
    d = defop.mesh.dim
    if samples.ndim != 3 or samples.shape[1:] != (n, d) or len(samples) == 0:
        raise ValueError(f"samples must have shape (k, {n}, {d}), k >= 1, for {n} moving handles, got {samples.shape}")
    if not np.isfinite(samples).all():
        raise ValueError("samples have NaN or infinite entries")
    return samples


def _ground_truth(defop, samples, X_true):
    X_true = opt.real_array("X_true", X_true)
    d = defop.mesh.dim
    if X_true.shape != (len(samples), defop.n_vertices, d):
        raise ValueError(f"X_true must have shape ({len(samples)}, {defop.n_vertices}, {d}), got {X_true.shape}")
    if not np.isfinite(X_true).all():  # the error was NaN, silently
        first = int(np.argwhere(~np.isfinite(X_true))[0, 0])
        raise ValueError(f"X_true has NaN or infinite entries (first in sample {first})")
    return X_true


def approximation_error(defop, samples, X_true, per_sample=False):
    """The paper's Fig. 8 metric, "(8a)/n over N held-out samples": (8a) summed over the N samples, divided by n.

    E_N = (1 / n_vertices) Σ_{k=1..N} ‖D^E(·, Q_k) − D(·, Q_k)‖²_{L²(Ω)}, the L² norm with the lumped mass
    matrix (Appendix A). A sum over the N = k configurations given: it grows with N, so a label states N
    ("(8a)/n over N = 100 held-out samples"). Divided by N it is the "mean (8a)/n per sample" (docs/glossary.md).

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
        (8a)/n over N = k samples.
    terms : (k,) numpy array, only with ``per_sample``
        Each configuration's own (8a)/n (N = 1); they sum to ``error``.
    """
    samples = _samples(defop, samples)
    X_true = _ground_truth(defop, samples, X_true)
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
    samples = _samples(defop, samples)
    D = defop(samples)
    X_true = _ground_truth(defop, samples, X_true)
    return float(np.sqrt(np.mean(np.sum((D - X_true) ** 2, axis=-1))) / defop.mesh.bbox_diagonal)


def flips(defop, samples):
    """Flipped triangles of D(·, Q_k) per sample.

    Returns
    -------
    counts : (k,) int numpy array
    """
    D = defop(_samples(defop, samples))
    return np.array([int(np.count_nonzero(defop.mesh.flipped(X))) for X in D])


def fit_timing(shape, samples, X, basis, spatial="hat", k=100, repeats=5):
    """Seconds of the least-squares fit (problem 8) alone, over ``repeats`` refits, BLAS on one thread.

    Table 1's LS column: the timed part of :func:`defop.operator.fit.fit` (its ``fit_time``, the structured solve
    :func:`~defop.operator.fit.structure`), once in a whole fit and then ``repeats - 1`` times alone. Φ is built once,
    outside the timed region, as the fit does.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
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

    from ..operator import fit as fit_mod
    from ..operator import spatial as spatial_mod

    if X is None:
        raise ValueError("fit_time needs the ground truths X (train with a ground-truth cache, or solve them)")
    phi = spatial_mod.make_spatial(shape.mesh, spatial, k)
    with threadpool_limits(limits=1):
        op = fit_mod.fit(shape.mesh, shape.handles, shape.moving, samples, X, basis, phi)
        times = [op.fit_time]
        for _ in range(max(1, int(repeats)) - 1):  # the timed part of a fit again (the fold is not timed)
            t0 = time.perf_counter()
            fit_mod.structure(op.handle_basis, op.train_samples)
            times.append(time.perf_counter() - t0)
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
        ``median`` and ``best`` seconds per call (wall clock), ``cpu_median`` and ``cpu_best`` (this thread's
        CPU time: without the time other jobs hold the core, though not without their cache traffic),
        ``repeats``, ``calls`` per run.
    """
    from threadpoolctl import threadpool_limits

    repeats = opt.integer("repeats", repeats, minimum=1)
    if not (isinstance(min_time, (int, float)) and 0 <= min_time < np.inf):
        raise ValueError(f"min_time must be a number of seconds >= 0, got {min_time!r}")
    with threadpool_limits(limits=1):
        f()  # warm-up: lazy copies, caches
        t0 = time.perf_counter()
        f()
        once = max(time.perf_counter() - t0, 1e-7)
        calls = max(1, int(min_time / once))
        runs, cpu = [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.thread_time()
            for _ in range(calls):
                f()
            cpu.append((time.thread_time() - c0) / calls)
            runs.append((time.perf_counter() - t0) / calls)
    return {
        "median": float(np.median(runs)),
        "best": float(np.min(runs)),
        "cpu_median": float(np.median(cpu)),
        "cpu_best": float(np.min(cpu)),
        "repeats": len(runs),
        "calls": calls,
    }


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
        ``median`` and ``best`` frames per second (from :func:`repeat_timing`), ``cpu_best`` (by CPU time),
        ``rank`` (None for the exact W_F) and ``dtype`` of the matrices a frame streams.
    """
    nxt = itertools.cycle(list(_samples(defop, samples))).__next__  # one frame per configuration, in turn
    evaluate = defop.evaluate_fast
    t = repeat_timing(lambda: evaluate(nxt()), repeats, min_time)
    dtype = str(defop.factors[1].dtype) if defop.factors is not None else "float32"
    return {
        "median": 1.0 / t["median"],
        "best": 1.0 / t["best"],
        "cpu_best": 1.0 / t["cpu_best"],
        "rank": defop.rank,
        "dtype": dtype,
    }


def batch_frame_rate(defop, samples, k=256, repeats=5, min_time=0.2):
    """Frames per second of ``defop.evaluate_batch`` on k configurations at once (one matrix product),
    into a reused output array, BLAS on one thread.

    Returns
    -------
    fps : dict
        ``median`` and ``best`` frames per second, ``cpu_best`` (by CPU time), and ``k``.
    """
    samples = _samples(defop, samples)
    k = opt.integer("k", k, minimum=1)
    Qs = samples[np.arange(k) % len(samples)]
    out = np.empty((k, defop.n_vertices, defop.mesh.dim))  # reused, as an animation loop would
    t = repeat_timing(lambda: defop.evaluate_batch(Qs, out=out), repeats, min_time)
    return {"median": k / t["median"], "best": k / t["best"], "cpu_best": k / t["cpu_best"], "k": k}


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


def sgemm_peak(n=1536, repeats=5):
    """Single-thread float32 matrix-product rate of this machine: 2n³ flops of a large numpy matmul (best run).

    Returns
    -------
    flops : float
        Floating-point operations per second.
    """
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((2, n, n), dtype=np.float32)
    c = np.empty_like(a)
    t = repeat_timing(lambda: np.matmul(a, b, out=c), repeats, min_time=0.0)
    return 2.0 * n**3 / t["best"]


def batch_floor(defop, k, peak, bandwidth, psi_seconds):
    """Lower bound on one frame's time in a batch of k: max(flops / peak, bytes written / bandwidth) + ψ.

    A batch frame multiplies δψ (|Ψ|−1) through the fast matrices (2·rows·cols flops each) and writes the
    float64 frame (16 bytes per vertex); the matrices are read once per batch, so their bytes per frame
    vanish as k grows.

    Parameters
    ----------
    defop : defop.operator.DefOp
    k : int
    peak : float
        Flops per second (:func:`sgemm_peak`).
    bandwidth : float
        Bytes per second (:func:`copy_bandwidth`).
    psi_seconds : float
        ψ of one frame, vectorised over the batch.

    Returns
    -------
    floor : dict
        ``seconds`` per frame, ``flops`` and ``bytes`` per frame, and which bound dominates (``bound``).
    """
    mats = defop.factors if defop.factors is not None else (defop.WF,)
    flops = float(sum(2 * M.shape[0] * M.shape[1] for M in mats))
    nbytes = 16.0 * defop.n_vertices + defop.factor_bytes(fast=True) / k
    compute, memory = flops / peak, nbytes / bandwidth
    return {
        "seconds": max(compute, memory) + psi_seconds,
        "flops": flops,
        "bytes": nbytes,
        "bound": "compute" if compute >= memory else "memory",
    }


def guarantee_errors(defop, samples):
    """Worst Prop. 2 and (8b) errors of ``defop.evaluate_fast`` over ``samples``, relative to the bbox diagonal.

    Returns
    -------
    errors : dict
        ``handles``: max |D(p_ℓ, Q) − q_ℓ| over the moving handles and the samples; ``rest``: max |D(·, P) − x|.
    """
    samples = np.asarray(samples, float)
    hv, diag = defop.handles[defop.moving], defop.mesh.bbox_diagonal
    handles = max(float(np.abs(defop.evaluate_fast(q)[hv] - q).max()) for q in samples)
    rest = float(np.abs(defop.evaluate_fast(defop.P) - defop.mesh.V).max())
    return {"handles": handles / diag, "rest": rest / diag}


def timing_row(shape, op, rec, samples, spatial="hat", k=100, tol=5e-3):
    """One row of Table 1 measured on this machine, BLAS on one thread: LS, FPS exact and compressed.

    The frame rates are :func:`frame_rate` of ``op.evaluate_fast`` with the guarantees on: first the exact
    operator (float32 W_F), then after ``op.compress(tol=tol)`` (rank r factors); ``op`` is left compressed.
    Preprocess is the training's own stage times (sampling, ground-truth solves, fit, fold): CPU seconds summed
    over the processes that solved (the sample engine's one timing rule), not wall seconds.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    op : defop.operator.DefOp
        Trained on ``shape`` (:func:`defop.training.bootstrap.train`), uncompressed.
    rec : training record
        With ``samples`` and ground truths ``X`` (for the LS refits).
    samples : (k,n,2) numpy array
        Configurations the frames cycle through.
    spatial : str
        Φ's kind, ``"hat"`` or ``"reduced"``.
    k : int
        Size of a reduced Φ.
    tol : float
        :meth:`DefOp.compress` tolerance.

    Returns
    -------
    row : dict
        Sizes (``tris``, ``verts``, ``moving``, ``fixed``, ``samples``, ``psi``, ``phi``; ``phi_paper``: |Φ| as
        the paper's Table 1 counts it, the number of triangles for the hat basis), ``preprocess_s``, ``ls_ms``
        best and median, ``fps_exact`` and ``fps`` (compressed) best and median with ``rank`` and ``dtype``, and
        the worst guarantee errors of both paths (``handles_err``, ``rest_err``, relative to the diagonal).
    """
    t = op.meta.get("stage_times", {})
    ls = fit_timing(shape, rec.samples, rec.X, op.handle_basis.kind, spatial, k)
    exact = frame_rate(op, samples)
    g_exact = guarantee_errors(op, samples)
    comp = frame_rate(op.compress(tol=tol), samples)
    g_comp = guarantee_errors(op, samples)
    mesh = shape.mesh
    return dict(
        tris=mesh.n_faces,
        verts=mesh.n_vertices,
        moving=op.n_moving,
        fixed=len(op.handles) - op.n_moving,
        samples=op.n_samples,
        psi=op.handle_basis.size,
        phi=op.meta["spatial_size"],
        phi_paper=mesh.n_faces if spatial == "hat" else op.meta["spatial_size"],
        preprocess_s=training_cpu(t),
        ls_ms=1e3 * ls["best"],
        ls_ms_median=1e3 * ls["median"],
        fps_exact=exact["best"],
        fps_exact_median=exact["median"],
        dtype_exact=exact["dtype"],
        fps=comp["best"],
        fps_median=comp["median"],
        rank=comp["rank"],
        dtype=comp["dtype"],
        handles_err=max(g_exact["handles"], g_comp["handles"]),
        rest_err=max(g_exact["rest"], g_comp["rest"]),
    )
