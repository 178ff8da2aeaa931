"""The joint training's solve policy, side by side: ``policy="full"`` (every joint sample solved from the rest pose on
the fine mesh) against ``"multilevel"`` (through the coarse level, :mod:`defop.training.multilevel`), at the budget.
(The logs in benchmarks/results ran ``"auto"`` when it was multilevel in 2D too: their "auto" rows are multilevel.)

Per shape (as :mod:`bench_movable` sets it up: the aleph, all 5 handles movable, regions of 5% of the diagonal;
``--dim 3`` bar_3d, its end-face patch movable, 8%): one fixed-P training at m = 200 (no cache), then the joint
training within the budget under each policy (:func:`~defop.training.movable_budget.train_within`, the one rule, as
``bench_movable.py``: the first m of one seeded sequence whose work reaches 5x the fixed-P training's, so each policy
gets its own m, the shorter sequence a prefix of the longer; no cache), each timed in CPU seconds (this process:
``DEFOP_N_JOBS=1``), its m, work ratio, solve and fit seconds printed apart; then the held-out error of both joint
operators over fixed-P operators retrained at each held-out placement (m = 200), against one truth (the full policy's,
cached). Printed with the load average. Run: ``python benchmarks/bench_movable_policy.py [aleph] [bar_3d]
[n_placements] [m_joint]`` (default the aleph and bar_3d, 3 placements x 10 Q: a reduced run; ``m_joint``: both
policies at that m (``train_movable``) instead of the budget, a reduced run printed as such).
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("DEFOP_N_JOBS", "1")

import bench_movable as bm  # noqa: E402

import defop as dop  # noqa: E402
from defop.training.movable import sample_joint, shape_at, solve_joint, train_movable  # noqa: E402
from defop.training.movable_budget import train_within  # noqa: E402

POLICIES = ("full", "multilevel")


def timed(f):
    c0 = time.process_time()
    out = f()
    return out, time.process_time() - c0


def run(name, n_place, m_joint=None, seed=0):
    shape, pr = bm.case(name, bm.CASES[name][0])
    mesh = shape.mesh
    print(
        f"\n== {name}: {mesh.n_vertices} vertices, regions {[len(v) for v in pr.vertices]}; load average "
        f"{os.getloadavg()[0]:.1f}",
        flush=True,
    )
    (op0, rec0), t_fixed = timed(
        lambda: dop.train(shape, "sarap", "tps", m=200, seed=seed, cache=False, progress=False)
    )
    asked = "the budget (train_within)" if m_joint is None else f"m={m_joint} given (REDUCED: not the budget)"
    print(f"fixed-P m=200 ({rec0.policy}): {t_fixed:.1f} CPU s, work {rec0.work:.3e}; joint at {asked}", flush=True)
    kw = {"seed": seed, "cache": False, "progress": False}
    ops = {}
    for pol in POLICIES:
        (opj, rec), t = timed(
            lambda pol=pol: (
                train_movable(shape, pr, "sarap", m=m_joint, policy=pol, **kw)
                if m_joint is not None
                else train_within(shape, pr, rec0, policy=pol, **kw)
            )
        )
        rules = rec.multilevel.get("rule") or []  # none on one level, nor from train_within (kept per block)
        fired = f"{sum(1 for r in rules if r)}/{len(rules)}" if rules else "-"
        why = rec.multilevel.get("fallback")
        work = f"work {(rec.work + rec.budget['fit']) / rec0.work:.2f}x, " if rec.budget else ""
        print(
            f"  joint policy={pol} ran {rec.policy} (coarse {rec.multilevel.get('coarse_vertices', '-')} vertices, "
            f"safeguard fired {fired}{', fallback: ' + why if why else ''}): m={len(rec.idx)}, {work}"
            f"{t:.1f} CPU s (solves {rec.solve_cpu_seconds:.1f}, fit {rec.fit_cpu_seconds:.1f}); ratio to fixed-P "
            f"{t / t_fixed:.2f}x; converged {int(rec.converged.sum())}/{len(rec.converged)}; load average "
            f"{os.getloadavg()[0]:.1f}",
            flush=True,
        )
        ops[pol] = opj
    idx, Q = sample_joint(shape, pr, n_place, np.random.default_rng(10_000 + seed), bm.N_Q)
    X, _ = solve_joint(shape, pr, idx, Q, progress=False)  # the full policy's truth, one for both
    errs = {pol: [] for pol in POLICIES}
    ret = []
    for p in range(n_place):
        sl = slice(p * bm.N_Q, (p + 1) * bm.N_Q)
        P = idx[sl][0]
        opr, _ = dop.train(shape_at(shape, pr, P), "sarap", "tps", m=200, seed=seed, progress=False)
        ret.append(bm.err8a(mesh, opr(Q[sl]), X[sl]))
        for pol, opj in ops.items():
            errs[pol].append(bm.err8a(mesh, opj(Q[sl], P=P), X[sl]))
    e_ret = float(np.mean(ret))
    ratios = {pol: float(np.mean(v)) / e_ret for pol, v in errs.items()}
    print(
        f"  held out {n_place} placements x {bm.N_Q} Q (REDUCED): joint / retrained "
        + ", ".join(f"{pol} {r:.3f}x" for pol, r in ratios.items())
        + f"; multilevel / full {ratios['multilevel'] / ratios['full']:.3f}; per placement multilevel / full "
        + str(np.round(np.array(errs["multilevel"]) / np.array(errs["full"]), 3).tolist())
        + f"; load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    args = sys.argv[1:]
    names = [a for a in args if a in bm.CASES] or ["aleph", "bar_3d"]
    nums = [int(a) for a in args if a not in bm.CASES]
    t0 = time.perf_counter()
    for name in names:
        run(name, nums[0] if nums else 3, nums[1] if len(nums) > 1 else None)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s wall; load average {os.getloadavg()[0]:.1f}")
