"""DefOp benchmark (issues 4, 13, 15): the aleph, 5 handles, S-ARAP, 500 samples, TPS, next to Table 1.

Prints, from one run, with the guarantees on (Prop. 2 and (8b) hold on every path by construction, see
``defop.operator.defop``; the run checks them on the held-out configurations):

* preprocess time (sampling + ground-truth solves + fit), the fit (structured least squares) and fold;
* single-thread frame rates (BLAS pinned to one thread with threadpoolctl; median and best of 15 short runs) of
  the exact operator in float64 and float32 W_F, and of the compressed one (rank r, float32), each beside
  its floor on this machine: the bytes of the matrices a frame streams over the bandwidth of a large numpy
  copy (read + write), plus the ψ time; and the batch API (k = 256 frames), beside its floor
  max(flops / sgemm peak, bytes written / bandwidth) + ψ, with the most that floor allows against the 10x
  target; FPS also by the thread's CPU time (the machine is shared), and the load average;
* on ≥ 50 held-out configurations (``train.held_out``): the (8a) error the compression adds (target
  ≤ 1%), flipped triangles per frame (target: no more than the exact operator), and the worst handle and
  rest-pose errors of every path (target ≤ 1e-9 of the bounding-box diagonal);
* libigl ARAP's 10-iteration solve on the same mesh, as a ratio.

The paper's Table 1 row for the aleph (S-ARAP, 500 samples, TPS): preprocess 2,500 s, LS 91 ms, 2,050 FPS.
Targets (issue 15): compressed ≥ 40,000 FPS, exact ≥ 2,050 FPS, batch ≥ 10x single-frame throughput.

Run: ``python benchmarks/bench_operator.py [m] [--cache] [--octopus]``. Without ``--cache`` nothing is
cached (preprocess is measured from scratch); ``--octopus`` adds the octopus (TPS-1000, reduced Φ)
guarantee and error rows, trained through ``DEFOP_CACHE``.
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

import defop as dop
from defop.analysis.metrics import (
    approximation_error,
    batch_floor,
    batch_frame_rate,
    copy_bandwidth,
    flips,
    frame_rate,
    repeat_timing,
    sgemm_peak,
)
from defop.operator.defop import ExtrapolationWarning

N_TEST = 60  # held-out configurations (issue 15: at least 50)
TOL = 5e-3  # compress(): discarded part of the training displacements (aleph: rank 30, +0.03% (8a))


def guarantees(op, Q):
    """Worst handle and rest-pose errors over Q of every path, relative to the bounding-box diagonal."""
    diag = op.mesh.bbox_diagonal
    hv, P, V = op.handles[op.moving], op.P, op.mesh.V
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        paths = {
            "op(Q)": (op(Q), op(P)),
            "evaluate_fast": (np.array([op.evaluate_fast(q) for q in Q]), op.evaluate_fast(P)),
            "evaluate_batch": (op.evaluate_batch(Q), op.evaluate_batch(P[None])[0]),
        }
    return {k: (np.abs(D[:, hv] - Q).max() / diag, np.abs(D0 - V).max() / diag) for k, (D, D0) in paths.items()}


def quality_rows(name, op, Q, X):
    """(8a) error and flips per frame, exact vs compressed, and the guarantees of every path."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        far = op.P + 10 * op.mesh.bbox_diagonal * np.random.default_rng(1).standard_normal((8, *op.P.shape))
        err, fl = approximation_error(op, Q, X), flips(op, Q).mean()
        rounding = np.abs(op.evaluate_batch(Q) - op(Q)).max() / op.mesh.bbox_diagonal  # float32 W_F vs float64
        g = guarantees(op, np.concatenate([Q, far]))
        op.compress(tol=TOL)
        err_c, fl_c = approximation_error(op, Q, X), flips(op, Q).mean()
        g_c = guarantees(op, np.concatenate([Q, far]))
        rank = op.rank
        op.decompress()
    print(f"\n{name}: {op.n_vertices} vertices, {len(Q)} held-out Q (+ 8 at 10x the diagonal for the guarantees)")
    print(f"  {'':34s} {'exact W':>12s} {f'rank {rank}':>12s}")
    print(
        f"  {'(8a) error / n_vertices':34s} {err:12.4e} {err_c:12.4e}   (+{100 * (err_c / err - 1):.3f}%, target <= 1%)"
    )
    print(f"  {'flipped triangles per frame':34s} {fl:12.3f} {fl_c:12.3f}   (target: compressed <= exact)")
    print(f"  float32 vs float64 W_F, max |difference| / diag: {rounding:.1e} (rounding; guarantees stay exact)")
    for path in g:
        print(f"  {'|handle - Q|/diag, ' + path:34s} {g[path][0]:12.1e} {g_c[path][0]:12.1e}   (target <= 1e-9)")
        print(f"  {'|D(P) - x|/diag, ' + path:34s} {g[path][1]:12.1e} {g_c[path][1]:12.1e}   (target <= 1e-9)")


def psi_times(op, Q, k):
    """ψ seconds of one frame: on its own (the single-frame path) and vectorised over a batch of k."""
    hb, f = op.handle_basis, op._fast_state()
    dz = (Q[0] - op.P).ravel()
    one = repeat_timing(lambda: hb.delta_raw(dz, dz @ dz, np.empty(hb.size - 1, f["dtype"])), 15, 0.01)
    dZ = (Q[np.arange(k) % len(Q)] - op.P).reshape(k, -1)
    zz = np.sum(dZ**2, axis=1)
    batch = repeat_timing(lambda: hb.delta_raw(dZ, zz, np.empty((k, hb.size - 1), f["dtype"])), 5, 0.05)
    return one["best"], batch["best"] / k


def speed_rows(op, Q, k=256):
    """Frame rates beside their floors, single thread, median and best of repeats; the batch beside its floor."""
    bw, peak = copy_bandwidth(), sgemm_peak()
    psi, psi_k = psi_times(op, Q, k)
    exact64 = repeat_timing(lambda: op(Q[0]), repeats=5)
    print(
        f"\nsingle thread (threadpoolctl), median / best of 15 runs (batch: 5); load average {os.getloadavg()[0]:.1f}; "
        f"copy bandwidth {bw / 1e9:.1f} GB/s, sgemm peak {peak / 1e9:.0f} GFLOPS; ψ {1e6 * psi:.1f} us a frame alone, "
        f"{1e6 * psi_k:.1f} us a frame in a batch of {k}"
    )
    head = (
        f"{'FPS median':>11s} {'FPS best':>10s} {'CPU best':>9s} {'floor us':>9s} {'best us':>8s} {'floor/best':>10s}"
    )
    print(f"  {'path':44s} {head}   floor")

    def row(label, fps, floor, why):
        print(
            f"  {label:44s} {fps['median']:11.0f} {fps['best']:10.0f} {fps.get('cpu_best', np.nan):9.0f} "
            f"{1e6 * floor:9.1f} {1e6 / fps['best']:8.1f} {floor * fps['best']:10.2f}   {why}"
        )

    def single(label, fps, fast=True):
        nbytes = op.factor_bytes(fast=fast)
        row(label, fps, nbytes / bw + psi, f"{nbytes / 1e6:.2f} MB / bandwidth + ψ")

    def batch(label, fps):
        fl = batch_floor(op, k, peak, bw, psi_k)
        why = f"max({fl['flops'] / 1e6:.2f} MFLOP / peak, {fl['bytes'] / 1e3:.0f} kB / bandwidth) + ψ"
        row(label, fps, fl["seconds"], why)
        return fl["seconds"]

    f64 = {k: 1 / exact64[k] for k in ("median", "best", "cpu_best")}
    single("exact, float64 W_F (op(Q), checked)", f64, False)
    f_exact = frame_rate(op, Q)
    single("exact, float32 W_F (evaluate_fast)", f_exact)
    b_exact = batch_frame_rate(op, Q, k)
    floor_exact = batch(f"exact, float32, batch k={k}", b_exact)
    op.compress(tol=TOL)
    f_comp = frame_rate(op, Q)
    single(f"compressed rank {op.rank} float32 (evaluate_fast)", f_comp)
    b_comp = batch_frame_rate(op, Q, k)
    floor_comp = batch(f"compressed rank {op.rank}, batch k={k}", b_comp)
    print(
        f"  exact float32 W_F: {f_exact['best'] / 2050:.2f}x the paper's 2,050 FPS (best; median "
        f"{f_exact['median'] / 2050:.2f}x); compressed: {f_comp['best'] / 40000:.2f}x the 40,000 FPS target (best; "
        f"median {f_comp['median'] / 40000:.2f}x)"
    )
    for name, b, f1, fl in (("exact", b_exact, f_exact, floor_exact), ("compressed", b_comp, f_comp, floor_comp)):
        most = 1 / (fl * f1["best"])  # the batch floor against the measured single frame
        print(
            f"  batch k={k} / single frame, {name}: {b['best'] / f1['best']:.1f}x best "
            f"({b['median'] / f1['median']:.1f}x median); target 10x; the batch floor allows at most {most:.1f}x "
            "on this machine" + ("" if most >= 10 else ": 10x is not reachable here")
        )
    print(
        "  (floor = bytes / copy bandwidth + ψ; factors that fit in cache can beat it, floor/best > 1; CPU best = FPS "
        "by this thread's CPU time, without the time other jobs held the core)"
    )
    op.decompress()
    return f_comp


def main(m=500, cache=False, octopus=False):
    if not cache:
        os.environ["DEFOP_CACHE"] = "off"
    shape = dop.shapes.load("aleph")
    t0 = time.perf_counter()
    op, rec = dop.train(shape, "sarap", "tps", m=m, seed=0, rounds=1, progress=True)
    preprocess = time.perf_counter() - t0
    Q, X, conv = dop.training.held_out(shape, "sarap", N_TEST, seed=12345, progress=True)
    fit_ms = 1e3 * dop.analysis.metrics.fit_time(shape, rec.samples, rec.X, "tps", "hat", repeats=5)
    print(
        f"\naleph: {shape.mesh.n_vertices} vertices, {shape.mesh.n_faces} triangles, {shape.n_moving} handles, "
        f"S-ARAP, {m} samples, TPS |Psi| = {op.handle_basis.size}, hat Phi; training solves converged "
        f"{int(rec.converged.sum())}/{m}, held-out {int(conv.sum())}/{N_TEST}"
    )
    if rec.cache == "none":
        stages = ", ".join(f"{k} {v:.2f}" for k, v in rec.stage_times.items())
        print(f"  preprocess {preprocess:.1f} s (paper 2,500 s, target <= 60 s; stages: {stages})")
    else:
        print(f"  preprocess: not measured (--cache, loaded the {rec.cache})")
    print(f"  fit, LS {fit_ms:.1f} ms (fastest of 5; paper 91 ms, target <= 20 ms)")
    quality_rows("aleph", op, Q, X)
    f_comp = speed_rows(op, Q)
    T = shape.targets(Q[0])
    arap10 = dop.rivals.solve_libigl_arap
    igl = repeat_timing(lambda: arap10(shape.mesh, shape.handles, T, iterations=10), 3, 0.0)
    print(
        f"\nlibigl ARAP, 10 iterations: {1e3 * igl['best']:.1f} ms per frame (best of 3) = "
        f"{igl['best'] * f_comp['best']:.0f}x one compressed DefOp frame"
    )
    if octopus:
        shape = dop.shapes.load("octopus")
        op, _ = dop.train(shape, "sarap", "tps", m=1000, spatial="reduced", k=100, seed=0, rounds=1)
        Q, X, _ = dop.training.held_out(shape, "sarap", N_TEST, seed=12345)
        quality_rows("octopus (TPS-1000, reduced Φ k=100)", op, Q, X)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(int(args[0]) if args else 500, cache="--cache" in sys.argv, octopus="--octopus" in sys.argv)
