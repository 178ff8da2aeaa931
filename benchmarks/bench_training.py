"""Training three times cheaper (issue 36): CPU seconds of ``train()`` per policy, side by side in one run.

Every row trains the same operator (a shape, S-ARAP, TPS, ``--samples`` samples, seed 0, one job) in a child process
of its own: a fresh interpreter, an empty ``DEFOP_CACHE`` of its own, one BLAS thread, and ``PYTHONPATH`` choosing
the code (main at d79f472 from a worktree, ``--base``, or this tree). Before the timed span the child imports defop
and solves one small problem, so imports and numba's (warm) on-disk cache are excluded; the timed span is ``train()``
alone, in CPU seconds of the process tree (``resource.getrusage``), wall time and load average beside. After it, the
child evaluates the operator on the held-out samples and computes the paper's (8a)/n over them
(``defop.analysis.metrics.approximation_error``), and the energy of every training sample.

The held-out truth (``dop.training.held_out``: 100 samples, seed 12345, rest-pose starts, main's full policy) is
solved once by main's code in a child of its own, outside every timed span, and kept in ``--truth-dir``.

Rows (one function each, :data:`ROWS`; a row returns the code path, extra environment and ``train`` keywords):

* ``main``: main at d79f472 (``--base``: ``git worktree add /tmp/base d79f472``);
* ``numpy``: this tree with the numpy element kernels (``DEFOP_KERNEL=numpy``), the reference path;
* ``kernel``: this tree with the fused numba kernels (:mod:`defop.variational.fused`, the default);
* ``multilevel``: the fused kernels and ``policy="multilevel"`` (``auto`` takes it from 10,000 vertices only).

Printed: per row CPU s, wall s, CPU ratio against main, held-out error and its ratio against main, verified samples,
and every training sample whose energy moved by more than 1e-6 relative to max(E_main, 1e-3 × median E_main).

Run: ``python benchmarks/bench_training.py --base /tmp/base [--shape aleph] [--samples 200] [--rows main kernel]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HELD_OUT, HELD_OUT_SEED = 100, 12345
#: a sample "moved" when its energy differs from main's by more than this, relative to max(E_main, 1e-3 median)
MOVED = 1e-6


def row_main(args):
    """main at d79f472, as it trains."""
    return {"path": args.base, "env": {}, "train": {}}


def row_numpy(args):
    """This tree, numpy element kernels (the reference path)."""
    return {"path": REPO, "env": {"DEFOP_KERNEL": "numpy"}, "train": {}}


def row_kernel(args):
    """This tree, fused numba kernels (the default)."""
    return {"path": REPO, "env": {"DEFOP_KERNEL": "numba"}, "train": {}}


def row_multilevel(args):
    """This tree, fused kernels and the multilevel policy (:mod:`defop.training.multilevel`) whatever the size."""
    return {"path": REPO, "env": {"DEFOP_KERNEL": "numba"}, "train": {"policy": "multilevel"}}


ROWS = {"main": row_main, "numpy": row_numpy, "kernel": row_kernel, "multilevel": row_multilevel}


def _env(path, extra, cache):
    env = {**os.environ, "PYTHONPATH": path, "DEFOP_CACHE": cache, "DEFOP_PROGRESS": "off", **extra}
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[k] = "1"
    return env


def _child(spec, env):
    """Run this file as a child with ``spec`` (JSON); its last stdout line is the JSON result."""
    out = subprocess.run(
        [sys.executable, os.path.abspath(__file__), "--child", json.dumps(spec)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode:
        raise RuntimeError(f"child failed ({spec['task']}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def truth(args):
    """Held-out Q and X (main's code, outside any timed span), kept as an npz in ``--truth-dir``."""
    path = os.path.join(args.truth_dir, f"{args.shape}_{HELD_OUT}_{HELD_OUT_SEED}.npz")
    if not os.path.exists(path):
        os.makedirs(args.truth_dir, exist_ok=True)
        with tempfile.TemporaryDirectory() as cache:
            spec = {"task": "truth", "shape": args.shape, "out": path}
            _child(spec, _env(args.base, {}, cache))
    return path


def run_row(name, args, truth_path):
    """One row in a child with an empty cache: its timings, error and sample energies."""
    row = ROWS[name](args)
    with tempfile.TemporaryDirectory() as cache:
        spec = {"task": "train", "shape": args.shape, "m": args.samples, "truth": truth_path, "train": row["train"]}
        load = os.getloadavg()[0]
        res = _child(spec, _env(row["path"], row["env"], cache))
    res["load"] = (load, os.getloadavg()[0])
    return res


def report(results):
    """The table, ratios against main's row (else the first), and the samples that moved."""
    base = results.get("main", results[next(iter(results))])
    E0 = np.array(base["energies"])
    scale = np.maximum(E0, 1e-3 * np.median(E0))
    print(
        f"{'row':>10} {'CPU s':>8} {'wall s':>8} {'CPU vs main':>12} {'(8a)/n':>11} {'err ratio':>9} "
        f"{'verified':>9} {'moved':>6}  load before/after"
    )
    for name, r in results.items():
        moved = np.flatnonzero(np.abs(np.array(r["energies"]) - E0) > MOVED * scale)
        r["moved"] = moved
        print(
            f"{name:>10} {r['cpu']:8.1f} {r['wall']:8.1f} {base['cpu'] / r['cpu']:11.2f}x {r['error']:11.4e} "
            f"{r['error'] / base['error']:9.3f} {r['converged']:>5}/{len(r['energies'])} {len(moved):6d}  "
            f"{r['load'][0]:.1f}/{r['load'][1]:.1f}"
        )
    if "numpy" in results and "kernel" in results:
        saved = 1 - results["kernel"]["cpu"] / results["numpy"]["cpu"]
        print(f"the fused kernels save {100 * saved:.0f}% of the training's CPU seconds against this tree's numpy path")
    for name, r in results.items():
        for k in r["moved"]:
            E = r["energies"][k]
            print(f"  {name}: sample {k} E {E:.9g} vs main {E0[k]:.9g} ({(E - E0[k]) / scale[k]:+.2e} of the scale)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="/tmp/base", help="worktree of main at d79f472")
    ap.add_argument("--shape", default="aleph")
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--rows", nargs="+", default=["main", "kernel"], choices=list(ROWS))
    ap.add_argument("--truth-dir", default=os.path.join(tempfile.gettempdir(), "defop-bench-training"))
    ap.add_argument("--child")
    args = ap.parse_args()
    if args.child:
        return child(json.loads(args.child))
    if not os.path.isdir(os.path.join(args.base, "defop")):
        raise SystemExit(f"--base {args.base!r} is not a worktree of main: git worktree add {args.base} d79f472")
    print(f"{args.shape}, S-ARAP, TPS, m = {args.samples}, 1 job, one BLAS thread; {time.strftime('%Y-%m-%d %H:%M')}")
    truth_path = truth(args)
    results = {}
    for name in args.rows:
        results[name] = run_row(name, args, truth_path)
        print(f"  {name}: {results[name]['cpu']:.1f} CPU s", flush=True)
    report(results)


# ---------------------------------------------------------------------------------------------- the child side
def _cpu():
    import resource

    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def child(spec):
    import warnings

    import defop as dop

    warnings.simplefilter("ignore")
    shape = dop.shapes.load(spec["shape"])
    if spec["task"] == "truth":
        Q, X, ok = dop.training.held_out(shape, "sarap", HELD_OUT, HELD_OUT_SEED, n_jobs=1, progress=False)
        np.savez(spec["out"], Q=Q, X=X, converged=ok)
        print(json.dumps({"converged": int(np.sum(ok))}))
        return
    small = dop.shapes.load("bar")  # warm-up: lazy imports, numba's cached kernels
    dop.variational.Solver(small.mesh, small.handles, "sarap").solve(small.targets(small.P_moving + 0.01))
    c0, w0 = _cpu(), time.perf_counter()
    op, rec = dop.train(shape, "sarap", "tps", m=spec["m"], seed=0, n_jobs=1, progress=False, **spec["train"])
    cpu, wall = _cpu() - c0, time.perf_counter() - w0
    held = np.load(spec["truth"])
    error = float(dop.analysis.metrics.approximation_error(op, held["Q"], held["X"]))
    solver = dop.variational.Solver(shape.mesh, shape.handles, "sarap")
    if hasattr(solver, "kernel"):
        solver.kernel = "numpy"  # every row's energies by the same formulas
    energies = [float(solver.energy_of(X)) for X in rec.X]
    out = {"cpu": cpu, "wall": wall, "error": error, "converged": int(np.sum(rec.converged)), "energies": energies}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
