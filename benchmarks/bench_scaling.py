"""How training and evaluation scale with the mesh (issue 15): aleph-like meshes of 1k, 3k, 10k, 30k vertices.

For each size, in its own process, with 5 handles, S-ARAP, 500 samples (the issue's target), TPS:

* one cold S-ARAP solve (from the solver's own start) and one warm-started solve (from the solution of a
  nearby configuration), median of 3 each, single-thread BLAS (threadpoolctl);
* **preprocess**: with ``--real`` (the default at 1k and 3k; ``--real-sizes`` chooses) the real training,
  ``train.train(shape, "sarap", "tps", m=500, cache=False)`` with its defaults (``rounds=2``, one job per
  core), is run and timed, with the load average during the run (the machine is shared). Elsewhere it is
  **estimated**: a model of the solves (2n + 1 = 11 bootstrap samples cold, the other 489 twice warm, plus the
  fit), times the calibration real / model measured at the sizes trained for real; both are printed;
* the fit (problem 8) and fold, and the exact W's size (|Ψ| × 2 n_vertices float64). The fit's cost does
  not depend on the data, so it fits synthetic smooth deformations (not the S-ARAP ones);
* single-frame FPS of the compressed operator at rank 50, median and best of 7, guarantees on;
* **peak RSS** of the size's process tree (its own process plus the training's worker processes, sampled
  every second with psutil) and of the process alone (``ru_maxrss``).

Each column gets a fitted exponent (least squares on log n). Run: ``python benchmarks/bench_scaling.py``;
``--one N [--real]`` measures one size and prints its row as JSON, ``--rows FILE...`` prints the table from
saved rows (so a long 30k run can be measured once and tabulated with the others).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import threading
import time

import numpy as np

SIZES = (1000, 3000, 10000, 30000)
REAL_SIZES = (1000, 3000)
M = 500
RANK = 50


def _median_time(f, repeats=3):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


class _TreeMonitor:
    """Peak RSS of this process and its children (joblib's workers), their CPU seconds (user + system, the last
    value seen per process) and the load average, every second."""

    def __init__(self):
        import psutil

        self._me = psutil.Process()
        self.peak, self.loads, self._cpu = 0, [], {}
        self._cpu0 = sum(self._me.cpu_times()[:2])
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        import psutil

        while not self._stop.is_set():
            rss = 0
            for p in [self._me, *self._me.children(recursive=True)]:
                try:
                    rss += p.memory_info().rss
                    self._cpu[p.pid] = sum(p.cpu_times()[:2])
                except psutil.Error:
                    pass
            self.peak = max(self.peak, rss)
            self.loads.append(os.getloadavg()[0])
            self._stop.wait(1.0)

    @property
    def cpu_seconds(self):
        """CPU seconds of the process tree since the monitor started."""
        return sum(self._cpu.values()) - self._cpu0

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def _solve_and_fit(shape, Q, rng):
    """Cold and warm solve times, the fit, W's size and the compressed FPS (one thread)."""
    import defop as dop

    mesh = shape.mesh
    out = {}
    solver = dop.variational.Solver(mesh, shape.handles, "sarap")
    first = solver.solve(shape.targets(Q[0]))
    out["t_cold"] = _median_time(lambda: solver.solve(shape.targets(Q[1])))
    near = shape.P_moving + 0.9 * (Q[0] - shape.P_moving)  # a nearby configuration, warm-started from Q[0]'s
    out["t_warm"] = _median_time(lambda: solver.solve(shape.targets(near), X0=first.X))
    # synthetic smooth deformations: the fit's cost does not depend on the data
    a = 0.1 * rng.standard_normal((M, 2, 2))
    X = mesh.V + np.einsum("mij,vj->mvi", a, mesh.V - mesh.V.mean(0))
    t0 = time.perf_counter()
    op = dop.operator.fit.fit(mesh, shape.handles, shape.moving, Q, X, "tps", "hat")
    out["fit_fold"] = time.perf_counter() - t0
    nb = 2 * shape.n_moving + 1
    out["preprocess_model"] = nb * out["t_cold"] + 2 * (M - nb) * out["t_warm"] + out["fit_fold"]
    out["W_MB"] = op.W.nbytes / 1e6
    op.compress(rank=RANK)
    fps = dop.analysis.metrics.frame_rate(op, Q[:50])
    out["fps_best"], out["fps_median"], out["rank"] = fps["best"], fps["median"], op.rank
    return out


def one(n_vertices, real_training=False):
    """Measurements for one mesh size (run in a fresh process)."""
    import joblib
    from threadpoolctl import threadpool_limits

    import defop as dop

    shape = dop.shapes.load("aleph", n_vertices=n_vertices)
    rng = np.random.default_rng(0)
    Q = dop.training.sampling.sample_shape(shape, M, rng)
    out = {"n": shape.mesh.n_vertices, "faces": shape.mesh.n_faces}
    with threadpool_limits(limits=1):
        out.update(_solve_and_fit(shape, Q, rng))
    if real_training:
        with _TreeMonitor() as mon:
            t0 = time.perf_counter()
            # DEFOP_PROGRESS=text: progress bars on stderr (a long run can be followed)
            progress = bool(os.environ.get("DEFOP_PROGRESS"))
            _, rec = dop.train(shape, "sarap", "tps", m=M, seed=0, cache=False, progress=progress)
            out["preprocess_real"] = time.perf_counter() - t0
        out["converged"] = int(rec.converged.sum())
        out["stage_times"] = {k: round(v, 1) for k, v in rec.stage_times.items()}
        out["n_jobs"] = joblib.effective_n_jobs(dop.config.n_jobs())
        out["load_mean"], out["load_max"] = float(np.mean(mon.loads)), float(np.max(mon.loads))
        out["peak_rss_tree_MB"] = mon.peak / 1e6
        out["cpu_s"] = mon.cpu_seconds
    out["peak_rss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def exponent(n, y):
    """Slope of log y against log n (least squares)."""
    return float(np.polyfit(np.log(n), np.log(y), 1)[0])


def table(rows):
    """Print the table of measured rows (dicts from :func:`one`), with fitted exponents."""
    rows = sorted(rows, key=lambda r: r["n"])
    n = np.array([r["n"] for r in rows], float)
    reals = [r["preprocess_real"] / r["preprocess_model"] for r in rows if "preprocess_real" in r]
    calib = float(np.median(reals)) if reals else 1.0
    for r in rows:
        r["preprocess_est"] = r.get("preprocess_real", calib * r["preprocess_model"])
        r.setdefault("peak_rss_tree_MB", r["peak_rss_MB"])
    print(f"aleph-like meshes, 5 handles, S-ARAP, {M} samples, TPS; solves one thread; compressed at rank {RANK}")
    head = (
        "| vertices | cold solve s | warm solve s | fit+fold s | preprocess s: model, real (load) or *estimate* "
        "| exact W MB | compressed FPS best / median | peak RSS MB: process / with workers |"
    )
    print(head + "\n|" + "---|" * 8)
    for r in rows:
        if "preprocess_real" in r:
            real = (
                f"**real {r['preprocess_real']:.0f}** ({r['cpu_s']:.0f} CPU s, {r['n_jobs']} jobs, "
                f"load {r['load_mean']:.1f})"
            )
        else:
            real = f"*estimate {r['preprocess_est']:.0f}*"
        print(
            f"| {r['n']} | {r['t_cold']:.2f} | {r['t_warm']:.2f} | {r['fit_fold']:.2f} "
            f"| {r['preprocess_model']:.0f}, {real} | {r['W_MB']:.0f} | {r['fps_best']:.0f} / {r['fps_median']:.0f} "
            f"| {r['peak_rss_MB']:.0f} / {r['peak_rss_tree_MB']:.0f} |"
        )
    cols = ["t_cold", "t_warm", "fit_fold", "preprocess_est", "W_MB", "fps_best", "peak_rss_tree_MB"]
    exps = [f"n^{exponent(n, [r[c] for r in rows]):.2f}" for c in cols]
    print(f"| exponent (fit on log n) | {' | '.join(exps[:4])} | {' | '.join(exps[4:])} |")
    print(f"\ncalibration of the preprocess model (real / model at the sizes trained for real): {calib:.2f}")
    for r in rows:
        if "preprocess_real" in r:
            print(f"  {r['n']} vertices, real training: {r['converged']} of {M} converged, stages {r['stage_times']}")


def main(sizes=SIZES, real_sizes=REAL_SIZES):
    rows = []
    for n in sizes:
        cmd = [sys.executable, __file__, "--one", str(n)] + (["--real"] if n in real_sizes else [])
        res = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
        print(f"  measured {rows[-1]['n']} vertices", file=sys.stderr, flush=True)
    table(rows)


if __name__ == "__main__":
    args = sys.argv[1:]
    if "--one" in args:
        print(json.dumps(one(int(args[args.index("--one") + 1]), "--real" in args)))
    elif "--rows" in args:
        table([json.loads(open(f).read().strip().splitlines()[-1]) for f in args[args.index("--rows") + 1 :]])
    else:
        real = REAL_SIZES
        if "--real-sizes" in args:
            real = tuple(int(x) for x in args[args.index("--real-sizes") + 1].split(","))
        main(real_sizes=real)
