"""Multi-valued operators against the solver (issue 29): the bar of Fig. 10 and the U's arm pushed down.

For each case of :data:`defop.analysis.branches.CASES`: discover the branches on an n × n grid of one handle's
positions (the rest-pose multi-start at every sample plus two continuation sweeps across the folds), fit one DefOp
per branch and the single-valued DefOp (the lowest minimum per sample), then drag the handle along a
there-and-back path of ``steps`` steps each way and compare, frame by frame, with the solver's warm-started
continuation (the error of a frame: max vertex distance / bbox diagonal). Prints the branches, the training cost,
where each jumps, the errors, the energy excess of ``global`` and issue 29's three targets with pass/fail.

Run: ``python benchmarks/bench_branches.py [--n 17] [--steps 100] [--cases bar u_shape]`` (DEFOP_FAST=1: n = 9).
"""

from __future__ import annotations

import argparse
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
        f"training: single-valued solves {sec['single']:.1f} s; multi-valued {multi:.1f} s (sweeps "
        f"{sec['sweeps']:.1f} s, margins {B.margin_seconds:.1f} s) = {multi / sec['single']:.2f}x; fits "
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
    print(
        f"  error near the solver's jumps (±5 steps, {int(c.near.sum())} frames): follow mean "
        f"{c.follow[c.near].mean():.2e} max {c.follow[c.near].max():.2e}; single mean "
        f"{c.single[c.near].mean():.2e} max {c.single[c.near].max():.2e}"
    )
    print(
        f"  error elsewhere ({int((~c.near).sum())} frames): follow mean {c.follow[~c.near].mean():.2e} max "
        f"{c.follow[~c.near].max():.2e}; single mean {c.single[~c.near].mean():.2e} "
        f"max {c.single[~c.near].max():.2e}"
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
    ap.add_argument("--n", type=int, default=dop.config.pick(17, 9))
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--cases", nargs="+", default=list(ab.CASES))
    args = ap.parse_args()
    t0 = time.perf_counter()
    results = {}
    for name in args.cases:
        results[name] = report(ab.run_case(name, args.n, args.steps), args.steps)
    print(f"\nall targets met: {results}  ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
