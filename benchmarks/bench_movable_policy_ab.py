"""Interleaved A/B of the joint solves' CPU seconds: policy "full" against "multilevel" on the same samples, the
order alternating per repetition, no cache, this process only (``n_jobs=1``).

Run: ``python benchmarks/bench_movable_policy_ab.py NAME RADIUS SIZE SAMPLES REPS`` (SIZE 0: the catalogue's mesh;
RADIUS: the placement regions' share of the diagonal), e.g. ``aleph 0.05 0 10 4``, ``bar_3d 0.08 936 8 2``.
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

import defop as dop
from defop.scene.placement import placement_regions
from defop.training.movable import sample_joint, solve_joint


def main(name, radius, size, k, reps):
    shape = dop.shapes.load(name, size or None)
    pr = placement_regions(shape, radius=radius * shape.mesh.bbox_diagonal)
    idx, Q = sample_joint(shape, pr, 4, np.random.default_rng(99), 1)
    for pol in ("full", "multilevel"):  # warm: compiled kernels
        solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, cache=False, policy=pol)
    tot = {"full": 0.0, "multilevel": 0.0}
    for r in range(reps):
        idx, Q = sample_joint(shape, pr, k, np.random.default_rng(r), 1)
        for pol in ("full", "multilevel") if r % 2 == 0 else ("multilevel", "full"):
            t = time.process_time()
            solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, cache=False, policy=pol)
            tot[pol] += time.process_time() - t
        print(
            f"{name} {shape.mesh.n_vertices} rep {r}: full {tot['full']:.2f} s, multilevel {tot['multilevel']:.2f} s, "
            f"ratio full/ml {tot['full'] / tot['multilevel']:.2f}; load {os.getloadavg()[0]:.1f}",
            flush=True,
        )


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    a = sys.argv[1:]
    main(a[0], float(a[1]), int(a[2]), int(a[3]), int(a[4]))
