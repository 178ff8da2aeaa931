"""How training and evaluation scale with the mesh (issue 15): aleph-like meshes of 1k, 3k, 10k, 30k vertices.

For each size, in its own process (so that peak RSS is that size's), with 5 handles, S-ARAP, 200 samples,
TPS, single-thread BLAS (threadpoolctl):

* one cold S-ARAP solve (from the solver's own start) and one warm-started solve (from the solution of a
  nearby configuration), median of 3 each;
* **preprocess**: at 1k and 3k the real training (``train.train``, rounds=1, one job) is run and timed.
  The machine is shared, so at 10k and 30k it is **estimated**: training solves 2n + 1 = 11 bootstrap
  samples cold and the other 189 warm, so the model is 11 t_cold + 189 t_warm + the fit; the model is
  calibrated by the ratio real / model measured at 1k and 3k (its warm starts come from a linear fit,
  farther than the nearby start timed here), and both the model and the calibrated estimate are printed;
* the fit (problem 8) and fold, and the exact W's size (|Ψ| × 2 n_vertices float64). The fit's cost does
  not depend on the data, so it fits synthetic smooth deformations (not the S-ARAP ones);
* single-frame FPS of the compressed operator at rank 50 (the aleph TPS-500 needs rank 49 at tol = 1e-3),
  median and best of 7, guarantees on;
* peak RSS of the process.

Each column gets a fitted exponent (least squares on log n). Run: ``python benchmarks/bench_scaling.py``.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

import numpy as np

SIZES = (1000, 3000, 10000, 30000)
M = 200
RANK = 50


def _median_time(f, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def one(n_vertices, real_training=False):
    """Measurements for one mesh size (run in a fresh process)."""
    from threadpoolctl import threadpool_limits

    import defop as dop

    shape = dop.shapes.load("aleph", n_vertices=n_vertices)
    mesh = shape.mesh
    rng = np.random.default_rng(0)
    Q = dop.sampling.sample_shape(shape, M, rng)
    out = {"n": mesh.n_vertices, "faces": mesh.n_faces}
    with threadpool_limits(limits=1):
        solver = dop.solve.Solver(mesh, shape.handles, "sarap")
        first = solver.solve(shape.targets(Q[0]))
        out["t_cold"] = _median_time(lambda: solver.solve(shape.targets(Q[1])))
        near = shape.P_moving + 0.9 * (Q[0] - shape.P_moving)  # a nearby configuration, warm-started from Q[0]'s
        out["t_warm"] = _median_time(lambda: solver.solve(shape.targets(near), X0=first.X))
        nb = 2 * shape.n_moving + 1
        # synthetic smooth deformations: the fit's cost does not depend on the data
        a = 0.1 * rng.standard_normal((M, 2, 2))
        X = mesh.V + np.einsum("mij,vj->mvi", a, mesh.V - mesh.V.mean(0))
        t0 = time.perf_counter()
        op = dop.fit.fit(mesh, shape.handles, shape.moving, Q, X, "tps", "hat")
        out["fit_fold"] = time.perf_counter() - t0
        out["preprocess_model"] = nb * out["t_cold"] + (M - nb) * out["t_warm"] + out["fit_fold"]
        out["W_MB"] = op.W.nbytes / 1e6
        op.compress(rank=RANK)
        fps = dop.analysis.frame_rate(op, Q[:50])
        out["fps_best"], out["fps_median"], out["rank"] = fps["best"], fps["median"], op.rank
    if real_training:
        import os

        os.environ["DEFOP_CACHE"] = "off"
        t0 = time.perf_counter()
        dop.train.train(shape, "sarap", "tps", m=M, seed=0, rounds=1, n_jobs=1, cache=False, progress=False)
        out["preprocess_real"] = time.perf_counter() - t0
    out["peak_rss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def exponent(n, y):
    """Slope of log y against log n (least squares)."""
    return float(np.polyfit(np.log(n), np.log(y), 1)[0])


def main(sizes=SIZES):
    rows = []
    for n in sizes:
        cmd = [sys.executable, __file__, "--one", str(n)] + (["--real"] if n in sizes[:2] else [])
        res = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"  measured {rows[-1]['n']} vertices", file=sys.stderr, flush=True)
    n = np.array([r["n"] for r in rows], float)
    calib = float(np.median([r["preprocess_real"] / r["preprocess_model"] for r in rows if "preprocess_real" in r]))
    for r in rows:
        r["preprocess_est"] = r.get("preprocess_real", calib * r["preprocess_model"])
    print(f"aleph-like meshes, 5 handles, S-ARAP, {M} samples, TPS; one thread; compressed at rank {RANK}")
    head = (
        "| vertices | cold solve s | warm solve s | fit+fold s | preprocess s: model, real or *estimate* | exact W MB "
        "| compressed FPS best / median | peak RSS MB |"
    )
    print(head + "\n|" + "---|" * 8)
    for r in rows:
        real = f"real {r['preprocess_real']:.0f}" if "preprocess_real" in r else f"*estimate {r['preprocess_est']:.0f}*"
        print(
            f"| {r['n']} | {r['t_cold']:.2f} | {r['t_warm']:.2f} | {r['fit_fold']:.2f} "
            f"| {r['preprocess_model']:.0f}, {real} "
            f"| {r['W_MB']:.0f} | {r['fps_best']:.0f} / {r['fps_median']:.0f} | {r['peak_rss_MB']:.0f} |"
        )
    cols = ["t_cold", "t_warm", "fit_fold", "preprocess_est", "W_MB", "fps_best", "peak_rss_MB"]
    print(
        "| exponent (fit on log n) | " + " | ".join(f"n^{exponent(n, [r[c] for r in rows]):.2f}" for c in cols) + " |"
    )
    print(f"\ncalibration of the preprocess model (real / model at the sizes trained for real): {calib:.2f}")


if __name__ == "__main__":
    if "--one" in sys.argv:
        print(json.dumps(one(int(sys.argv[sys.argv.index("--one") + 1]), "--real" in sys.argv)))
    else:
        main()
