"""Does work predict CPU seconds? The joint budget's proxy (:mod:`defop.training.work`) beside the CPU seconds it
stands for, side by side in one process.

Per shape: one fixed-P training at m = 200 (``dop.train``, no cache), then the joint solves of the first ``m_joint``
samples of the seeded sequence (:func:`defop.training.movable.solve_joint`'s engine, no cache, one call: one solver
per placement), each after a small training has compiled the kernels. Printed: each side's CPU seconds of solves and
its work, and the two ratios (joint / fixed-P), whose quotient is how far the proxy is from the CPU seconds (1: exact).

Run: ``python benchmarks/bench_work_budget.py [m_joint] [bar] [aleph] [octopus] [bar_3d]`` (default 150, all four;
``BENCH_MOVABLE_VERTICES`` reduces bar_3d as in ``bench_movable.py``), ``DEFOP_N_JOBS=1``, one BLAS thread.
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("DEFOP_N_JOBS", "1")

import defop as dop  # noqa: E402
from defop.training import movable as mv  # noqa: E402
from defop.training.movable_budget import stop_at  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
import bench_movable as bm  # noqa: E402


def row(name, m_joint):
    shape, pr = bm.case(name, bm.CASES[name][0])
    bm.warm(shape, pr)
    c0 = time.process_time()
    _, rec0 = dop.train(shape, "sarap", "tps", m=200, seed=0, cache=False, progress=False)
    t_fixed = time.process_time() - c0
    solve_fixed = sum(v for k, v in rec0.stage_times.items() if k not in ("fit", "fold", "load"))
    idx, Q = mv.sample_joint(shape, pr, m_joint, np.random.default_rng(0))
    c0 = time.process_time()
    _, _, _, _, used, info = mv._solve_joint(shape, pr, idx, Q, "sarap", 1, False, False, "auto", counted=True)
    t_joint = time.process_time() - c0
    _, w_joint = stop_at(info["work"], info["setup"], idx, np.inf)
    cpu, work = t_joint / solve_fixed, w_joint / rec0.work
    print(
        f"{name} ({shape.mesh.n_vertices} vertices): fixed-P m=200 {rec0.policy}: {t_fixed:.2f} CPU s "
        f"({solve_fixed:.2f} solves), work {rec0.work:.4e}; joint {m_joint} ({used}, "
        f"{len(np.unique(idx, axis=0))} placements): {t_joint:.2f} CPU s, work {w_joint:.4e}; joint / fixed-P: CPU "
        f"{cpu:.3f}, work {work:.3f}, work / CPU {work / cpu:.2f}; load average {os.getloadavg()[0]:.1f}",
        flush=True,
    )
    return work / cpu


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    args = sys.argv[1:]
    m = next((int(a) for a in args if a.isdigit()), 150)
    names = [a for a in args if not a.isdigit()] or ["bar", "aleph", "octopus", "bar_3d"]
    q = [row(n, m) for n in names]
    print(f"work / CPU ratio {min(q):.2f}-{max(q):.2f}; load average {os.getloadavg()[0]:.1f}")
