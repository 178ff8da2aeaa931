"""Multi-valued operators (issue 29): the bar of Fig. 10, the U's arm pushed down, and the bar in 3D (plank_3d).

For each case of :data:`defop.analysis.branches.CASES`: discover the branches on an n × n grid of one handle's
positions (in 3D: the plank's end handle in the plane z = const; the rest-pose multi-start at every sample plus two
continuation sweeps across the folds), fit one DefOp per branch and the single-valued DefOp (the lowest minimum per
sample), then drag the handle along a there-and-back path of ``steps`` steps each way and compare, frame by frame,
with the solver's warm-started continuation (the error of a frame: max vertex distance / bbox diagonal). Prints the
branches, the training cost in CPU seconds of this process, where each jumps, the errors, the energy excess of
``global`` and issue 29's three targets with pass/fail, and the load average.

Run: ``python benchmarks/bench_branches.py [--n N] [--steps 100] [--cases bar u_shape plank_3d]`` (default n: the
case's, :data:`defop.analysis.branches.CASES`: 17, 25, 17)
(DEFOP_FAST=1: n = 9). plank_3d takes about 20 minutes from an empty cache on one core.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import defop as dop
from defop.analysis import branches as ab


def report(case, steps):
    B, c, m = case.branches, case.comparison, case.minima
    print(
        f"\n=== {case.name}: {case.shape.mesh.n_vertices} vertices, {len(B.samples)} samples, path "
        f"{2 * steps} steps there and back ==="
    )
    sec = m.seconds
    multi = sec["single"] + sec["sweeps"] + B.margin_seconds
    print(
        f"training (CPU s): single-valued solves {sec['single']:.1f}; multi-valued {multi:.1f} (sweeps "
        f"{sec['sweeps']:.1f}, margins {B.margin_seconds:.1f}) = {multi / sec['single']:.2f}x; fits "
        f"{case.fit_seconds:.2f} s{' (solves read from the cache: costs as measured then)' if sec['cached'] else ''}"
    )
    print(f"distinct minima per sample: {np.bincount(B.distinct).tolist()} (index = count); conflicts {B.conflicts}")
    for r in B.reports():
        print(
            f"  branch {r['label']}: {r['count']} samples, q from {np.round(r['q_min'], 3)} to "
            f"{np.round(r['q_max'], 3)}, energy {r['energy'][0]:.3g} .. {r['energy'][1]:.3g}"
        )
    q = c.Qs[:, 0] - case.shape.P_moving[0]
    for who in ("solver", "follow", "single"):
        j = c.jumps[who]
        print(f"  {who:6s} jumps at frames {j.tolist()}  (q - p = {[tuple(np.round(q[k], 3)) for k in j]})")
    for where, frames in (("near the solver's jumps (±5 steps, ", c.near), ("elsewhere (", ~c.near)):
        if not frames.any():
            print(f"  error {where}0 frames): none")
            continue
        print(
            f"  error {where}{int(frames.sum())} frames): follow mean {c.follow[frames].mean():.2e} max "
            f"{c.follow[frames].max():.2e}; single mean {c.single[frames].mean():.2e} max {c.single[frames].max():.2e}"
        )
    print(f"  global's energy over the lowest verified minimum: max {c.excess.max():.2%}, mean {c.excess.mean():.2%}")
    ok = True
    for name, (value, passed) in ab.targets_met(c).items():
        shown = f"{value:.3g}" if np.isscalar(value) else value
        print(f"  target {'PASS' if passed else 'FAIL'}: {name} = {shown}")
        ok &= bool(passed)
    return ok


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=dop.config.pick(None, 9), help="samples per side (default: the case's n)")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--cases", nargs="+", default=list(ab.CASES))
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (2 cores: costs are CPU seconds of this process)")
    results = {}
    for name in args.cases:
        results[name] = report(ab.run_case(name, args.n, args.steps), args.steps)
    print(f"\nall targets met: {results}  ({time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
