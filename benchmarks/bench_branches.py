"""Multi-valued operators on the catalogue and on random bistable shapes (issues 29 and 37).

For each case: discover the branches on the grid of :data:`defop.analysis.branches.PARAMS` around the case's path
(the same parameters for every case: n × n samples of the moving handle, half width, centre at the path's
midpoint, one continuation sweep), certify each branch's presence and absence at every sample bordering its
domain and bisect towards its folds (:mod:`defop.training.branches.certify`), fit one DefOp per branch with its
domain function and the single-valued DefOp (the lowest minimum per sample), then drag the handle along the
there-and-back path (100 steps each way) and compare, frame by frame, with the solver's warm-started continuation
(the error of a frame: max vertex distance / bbox diagonal). Prints per case the branches, certified / uncertified
samples, samples with more than two minima, the training cost in CPU seconds (multi-valued: sweeps, certification
and bisection; single-valued: the rest-pose multi-start), where each jumps, the errors, ``follow``'s frame time
against a DefOp frame, issue 37's targets with pass/fail, and the load average. Exit status 1 when one of the
bar's targets that lesson 15 states fails (the training cost, a CPU-time ratio, among them).

``--random N``: the first N accepted cases of :func:`defop.lessons.random_branches.random_cases` (seeds 0, 1, …;
rejected seeds printed with the reason). ``--cases``: catalogue cases (default bar u_shape; plank_3d takes about
20 minutes on one core).

Run: ``python benchmarks/bench_branches.py [--random N] [--cases bar u_shape plank_3d] [--n N]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

from defop.analysis import branches as ab
from defop.lessons import random_branches as rb


def frame_times(case, repeat=5):
    """(follow, DefOp) CPU seconds per frame along the case's path (``time.process_time``: what else runs on the
    machine does not count): the best of ``repeat`` interleaved runs over the path's frames."""
    Qs = case.comparison.Qs
    op = case.operator.branches[0].op
    best = [np.inf, np.inf]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(repeat):
            s = case.operator.session()
            t0 = time.process_time()
            for q in Qs:
                s(q)
            t1 = time.process_time()
            for q in Qs:
                op(q)
            t2 = time.process_time()
            best = [min(best[0], (t1 - t0) / len(Qs)), min(best[1], (t2 - t1) / len(Qs))]
    return best


def report(case, catalogue):
    B, c, m = case.branches, case.comparison, case.minima
    print(f"\n=== {case.name}: {case.shape.mesh.n_vertices} vertices, {B.grid} grid samples ===")
    sec = m.seconds
    multi = sec["single"] + sec["sweeps"] + B.margin_seconds + B.certify_seconds
    cost = multi / sec["single"]
    cached = " (discovery read from the cache: its costs as measured then)" if sec["cached"] else ""
    print(
        f"training (CPU s): single-valued {sec['single']:.1f}; multi-valued {multi:.1f} (sweep {sec['sweeps']:.1f}, "
        f"certification + bisection {B.certify_seconds:.1f}) = {cost:.2f}x; fits {case.fit_seconds:.2f} s{cached}"
    )
    print(
        f"distinct minima per sample: {np.bincount(B.distinct[: B.grid]).tolist()} (index = count); conflicts "
        f"{B.conflicts}; samples with more than two minima: {B.third.tolist()}; found by certification {B.found}"
    )
    unc = 0
    for b in B.branches:
        on_grid = int((b.samples < B.grid).sum())
        unc += len(b.uncertified)
        print(
            f"  branch {b.label}: present at {on_grid} samples, certified absent at {len(b.absent)}, uncertified "
            f"{len(b.uncertified)} {b.uncertified.tolist()}; {len(b.folds)} fold points, {len(b.samples) - on_grid} "
            "edge minima"
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ex = case.operator.exists(B.samples[: B.grid])
    disagree = sum(
        int((~ex[b.samples[b.samples < B.grid], b.label]).sum()) + int(ex[b.absent, b.label].sum()) for b in B.branches
    )
    print(f"  exists_b against the certified labels: {disagree} disagreements; {unc} uncertified samples")
    for who in ("solver", "follow", "single"):
        print(f"  {who:6s} jumps at frames {c.jumps[who].tolist()}")
    f_near, s_near, used = ab.near_error(c)
    print(
        f"  near the jumps ({used} frames, ±5 steps, the worst frame per jump left out): follow {f_near:.2e}, single "
        f"{s_near:.2e} ({s_near / max(f_near, 1e-300):.1f}x); elsewhere follow {c.follow[~c.near].mean():.2e}, "
        f"single {c.single[~c.near].mean():.2e}"
    )
    tf, td = frame_times(case)
    print(f"  frame (CPU): follow {tf * 1e6:.0f} us, DefOp {td * 1e6:.0f} us = {tf / td:.2f}x (target <= 2)")
    targets = ab.targets_met(c, catalogue=catalogue, cost=cost)
    targets["follow frame / DefOp frame <= 2"] = (tf / td, tf / td <= 2)
    for name, (value, passed) in targets.items():
        shown = f"{value:.3g}" if np.isscalar(value) else value
        print(f"  target {'PASS' if passed else 'FAIL'}: {name} = {shown}")
    return {name: bool(passed) for name, (_, passed) in targets.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=None, help="samples per side (default: PARAMS' n)")
    ap.add_argument("--cases", nargs="*", default=["bar", "u_shape"])
    ap.add_argument("--random", type=int, default=0, help="the first N accepted random cases")
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (2 cores: costs are CPU seconds of this process)")
    print(f"parameters for every case: {ab.PARAMS}, FOLLOW_RATIO {ab.br.FOLLOW_RATIO}")
    results = {}
    for name in args.cases:
        results[name] = report(ab.run_case(name, args.n), catalogue=True)
    if args.random:
        print(f"\nrandom cases: the first {args.random} accepted from seeds 0, 1, 2, ...")
        for case, truth in rb.random_cases(args.random):
            results[case.shape.name] = report(rb.run_random(case, truth), catalogue=False)
    print("\nsummary (cases passing each target):")
    names = sorted({t for r in results.values() for t in r})
    for t in names:
        passed = [k for k, r in results.items() if r.get(t)]
        print(f"  {t}: {len(passed)} of {len(results)}; failed: {[k for k in results if k not in passed]}")
    print(f"({time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f})")
    # the targets lesson 15 states for the bar (its training cost among them, a time the lesson does not assert)
    failed = [t for t, passed in results.get("bar", {}).items() if t in LESSON_TARGETS and not passed]
    print(f"the bar's lesson targets: {'all met' if not failed else f'FAILED {failed}'}")
    return not failed


#: the bar's targets that lesson 15 states (the follow frame's time is reported, not a lesson target)
LESSON_TARGETS = (
    "jumps: as many as the solver, each within 1 step",
    "near the jumps: follow mean error / diagonal <= 1e-2",
    "elsewhere: follow / single mean error <= 1.1 (catalogue), 1.5 (random)",
    "training cost multi / single <= 3",
)


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
