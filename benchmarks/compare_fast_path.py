"""Old vs new evaluation paths side by side in one process (issue 15): ``evaluate_fast`` and ``evaluate_batch``.

The old ``defop.operator.defop`` and ``defop.operator.handle_bases`` are taken from a git revision (``git
archive``) into a
temporary package ``defop_old``; both operators are built from the same trained aleph TPS-500 (S-ARAP, through
``DEFOP_CACHE``) and timed in alternation, BLAS on one thread: 15 rounds (batch: 11) of a short run each, per
frame, by wall clock and by this thread's CPU time (the machine is shared: CPU time leaves out the time other
jobs hold the core). Prints median and best FPS of each and the new/old ratios.

Run: ``python benchmarks/compare_fast_path.py [REV]`` (default 42d0365, before the raw-value fast paths).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import defop as dop


def old_package(rev, root):
    """Extract defop/ at ``rev`` as the package ``defop_old`` under ``root``; import its operator and bases."""
    repo = Path(__file__).resolve().parents[1]
    data = subprocess.run(["git", "archive", rev, "defop"], cwd=repo, check=True, capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(root, filter="data")
    (Path(root) / "defop").rename(Path(root) / "defop_old")
    sys.path.insert(0, str(root))
    return importlib.import_module("defop_old.operator"), importlib.import_module("defop_old.handle_bases")


def side(label, f_old, f_new, n, rounds, frames=1):
    """Alternate short runs of the two; print median / best FPS by wall clock and CPU time, and the ratios."""
    res = {k: {"wall": [], "cpu": []} for k in ("old", "new")}
    f_old(0), f_new(0)
    for _ in range(rounds):
        for key, f in (("old", f_old), ("new", f_new)):
            t0, c0 = time.perf_counter(), time.thread_time()
            for i in range(n):
                f(i)
            res[key]["wall"].append((time.perf_counter() - t0) / n / frames)
            res[key]["cpu"].append((time.thread_time() - c0) / n / frames)
    for clock in ("wall", "cpu"):
        o, w = res["old"][clock], res["new"][clock]
        print(
            f"  {label:30s} {clock:4s}  old {1 / np.median(o):8.0f} / {1 / min(o):8.0f}   "
            f"new {1 / np.median(w):8.0f} / {1 / min(w):8.0f} FPS (median / best)   "
            f"new/old {np.median(o) / np.median(w):.2f}x / {min(o) / min(w):.2f}x"
        )


def main(rev="42d0365", k=256):
    shape = dop.shapes.load("aleph")
    op, _ = dop.train(shape, "sarap", "tps", m=500, seed=0, rounds=1)
    Q = dop.training.sampling.sample_shape(shape, 20, np.random.default_rng(7))
    Qs = Q[np.arange(k) % len(Q)]
    qs = list(Q)
    out = np.empty((k, op.n_vertices, 2))
    with tempfile.TemporaryDirectory() as tmp:
        oldop, oldhb = old_package(rev, tmp)
        hb = op.handle_basis
        old = oldop.DefOp(
            op.mesh, op.handles, op.moving, oldhb.TPSBasis(hb.P, hb.centers, hb.scale), op.W, op.meta, op.train_samples
        )
        print(f"old = defop at {rev}, new = this tree; load average {os.getloadavg()[0]:.1f}; single thread")
        with threadpool_limits(limits=1):
            for compressed in (False, True):
                if compressed:
                    op.compress(tol=5e-3)
                    old.compress(tol=5e-3)
                print(f"compressed, rank {op.rank} float32" if compressed else "exact, float32 W_F")
                diff = np.abs(op.evaluate_fast(Q[1]) - old.evaluate_fast(Q[1])).max() / op.mesh.bbox_diagonal
                print(f"  max |new - old| / diag at a held-out Q: {diff:.1e}")
                n = 3000 if compressed else 300
                side(
                    "evaluate_fast",
                    lambda i: old.evaluate_fast(qs[i % 20]),
                    lambda i: op.evaluate_fast(qs[i % 20]),
                    n,
                    15,
                )
                side(
                    f"evaluate_batch k={k} (out=)",
                    lambda i: old.evaluate_batch(Qs, out=out),
                    lambda i: op.evaluate_batch(Qs, out=out),
                    5 if compressed else 1,
                    11,
                    frames=k,
                )
        print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
