"""Where a joint (P, Q) sample's CPU goes, beside a fixed-P sample (issue 44's budget), and the budget itself.

``python benchmarks/bench_joint_sample.py split NAME SIZE RADIUS K``: K joint samples (``solve_joint``, policy auto)
then one fixed-P training at m = 200, in this process (``n_jobs=1``), with the CPU seconds of solver construction,
the bi-Laplacian's LU and the factorisations (the first of a solver: its ordering and symbolic analysis too) per
sample on the fine and the coarse mesh.

``python benchmarks/bench_joint_sample.py budget NAME SIZE RADIUS M``: one fixed-P training at m = 200 and the joint
training at m = M (``train_movable``, no cache) side by side, their CPU ratio (what ``bench_movable.py`` prints as
"budget", without its held-out stage) and the peak RSS.

``python benchmarks/bench_joint_sample.py within NAME SIZE RADIUS ROUNDS``: the budget rule's CPU honesty: the fixed-P
training at m = 200 and ``train_within`` (no cache) alternated (fixed, joint, fixed, ... ROUNDS joint trainings), each
with its CPU seconds split by stage (solver construction, bi-Laplacian LU, factorisations per level; the rest: Python,
assembly, line search, fit) beside the work counted for it (factorisations, Hessian nonzeros K, setup, fit) and the
load average before and after, then the joint's work ratio beside its CPU ratio to the first and the mean fixed-P.

SIZE 0: the catalogue's mesh; RADIUS: the placement regions' share of the diagonal (2D 0.05, 3D 0.08 as
``bench_movable.py``). Set ``DEFOP_N_JOBS=1`` and one BLAS thread.
"""

from __future__ import annotations

import collections
import functools
import os
import resource
import sys
import time
import warnings

import numpy as np

import defop as dop
from defop.scene.placement import placement_regions
from defop.training import work as work_mod
from defop.training.movable import budget_samples, sample_joint, solve_joint, train_movable
from defop.training.movable_budget import train_within
from defop.variational import problem as pb
from defop.variational import solver as sv
from defop.variational import work as vwork


def instrument(n_fine):
    """Count CPU seconds per stage (fine / coarse by the mesh size) in a dict, by wrapping three functions."""
    acc = collections.defaultdict(float)

    def timed(label, f):
        t, w = time.process_time(), vwork.total()
        try:
            return f()
        finally:
            acc[label] += time.process_time() - t
            acc["n " + label] += 1
            acc["w " + label] += vwork.total() - w

    def level(n):
        return " fine" if n == n_fine else " coarse"

    factorise, factors, init = pb.ReducedHessian._factorise, pb.biharmonic_factors, sv.Solver.__init__

    def hessian_factorise(self, K, b):
        what = "factorisation, first" if self._factor is None else "factorisation, update"
        acc["K " + what + level(self.n_vertices)] += K.nnz
        return timed(what + level(self.n_vertices), lambda: factorise(self, K, b))

    def biharmonic(mesh, free, handles):
        out = timed("bi-Laplacian LU" + level(mesh.n_vertices), lambda: factors(mesh, free, handles))
        acc["K bi-Laplacian LU" + level(mesh.n_vertices)] += out[0].L.nnz + out[0].U.nnz  # its LU's nonzeros
        return out

    def solver_init(self, mesh, *a, **kw):
        return timed("Solver()" + level(mesh.n_vertices), lambda: init(self, mesh, *a, **kw))

    init_hessian = pb.ReducedHessian.__init__

    def hessian_init(self, mesh, free, backend=None):
        init_hessian(self, mesh, free, backend)
        self.n_vertices = mesh.n_vertices

    pb.ReducedHessian.__init__ = hessian_init
    pb.ReducedHessian._factorise = hessian_factorise
    pb.biharmonic_factors = biharmonic
    sv.Solver.__init__ = solver_init
    return acc


def case(name, size, radius):
    shape = dop.shapes.load(name, size or None)
    return shape, placement_regions(shape, radius=radius * shape.mesh.bbox_diagonal)


def split(name, size, radius, k):
    shape, pr = case(name, size, radius)
    acc = instrument(shape.mesh.n_vertices)
    idx, Q = sample_joint(shape, pr, 2, np.random.default_rng(99))
    solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, cache=False, policy="auto")  # compiled kernels
    acc.clear()
    idx, Q = sample_joint(shape, pr, k, np.random.default_rng(1))
    t = time.process_time()
    solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, cache=False, policy="auto")
    tj, joint = time.process_time() - t, dict(acc)
    acc.clear()
    t = time.process_time()
    _, rec = dop.train(shape, "sarap", "tps", m=200, seed=0, cache=False, progress=False, n_jobs=1)
    tf, fixed = time.process_time() - t, dict(acc)
    print(
        f"{name}, {shape.mesh.n_vertices} vertices, {len(np.unique(idx, axis=0))} placements in {k} joint samples; "
        f"per sample: joint {tj / k * 1e3:.1f} ms, fixed-P {tf / 200 * 1e3:.1f} ms ({rec.policy}), ratio "
        f"{tj / k / (tf / 200):.2f}; load average {os.getloadavg()[0]:.2f}"
    )
    for key in sorted(x for x in {*joint, *fixed} if not x.startswith(("n ", "w ", "K "))):
        j, f = joint.get(key, 0.0) / k, fixed.get(key, 0.0) / 200
        nj, nf = joint.get("n " + key, 0) / k, fixed.get("n " + key, 0) / 200
        print(f"  {key:32s} joint {j * 1e3:6.1f} ms ({nj:5.2f} calls)   fixed-P {f * 1e3:6.1f} ms ({nf:5.2f} calls)")


def budget(name, size, radius, m):
    shape, pr = case(name, size, radius)
    train_movable(shape, pr, m=4, seed=123, cache=False, progress=False)  # compiled kernels
    c0 = time.process_time()
    _, rec0 = dop.train(shape, "sarap", "tps", m=200, seed=0, cache=False, progress=False)
    t_fixed = time.process_time() - c0
    print(
        f"{name}, {shape.mesh.n_vertices} vertices: fixed-P m=200 {t_fixed:.1f} CPU s ({rec0.policy}), budget m "
        f"{budget_samples(rec0)}; load average {os.getloadavg()[0]:.2f}",
        flush=True,
    )
    c0 = time.process_time()
    _, rec = train_movable(shape, pr, m=m, seed=0, cache=False, progress=False)
    t_joint = time.process_time() - c0
    print(
        f"joint m={m} ({rec.policy}, {len(np.unique(rec.idx, axis=0))} placements): {t_joint:.1f} CPU s (solves "
        f"{rec.solve_cpu_seconds:.1f}, fit {rec.fit_cpu_seconds:.1f}); budget {t_joint / t_fixed:.2f}x (target <= 5x); "
        f"a joint sample / a fixed-P sample {rec.solve_cpu_seconds / m / (t_fixed / 200):.2f}; converged "
        f"{int(rec.converged.sum())}/{m}; peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; "
        f"load average {os.getloadavg()[0]:.2f}"
    )


def staged(acc, run):
    """Run ``run()`` with the stage counters cleared and a work tally open: (its result, CPU s, the stages' CPU and
    work and calls, the tally, load averages before and after)."""
    acc.clear()
    load0, t = os.getloadavg()[0], time.process_time()
    with work_mod.tally() as tal:
        out = run()
    return out, time.process_time() - t, dict(acc), tal, (load0, os.getloadavg()[0])


def within(name, size, radius, rounds):
    """The budget rule's CPU honesty: the fixed-P training at m = 200 and ``train_within`` (no cache) alternated
    ``rounds`` times in this process (fixed, joint, fixed, ...), each split by stage beside the work counted for it."""
    shape, pr = case(name, size, radius)
    n = shape.mesh.n_vertices
    acc = instrument(n)
    dop.train(shape, "sarap", "tps", m=40, seed=1, cache=False, progress=False)  # compiled kernels
    idx, Q = sample_joint(shape, pr, 2, np.random.default_rng(1))
    solve_joint(shape, pr, idx, Q, progress=False, cache=False)

    def fixed():
        return dop.train(shape, "sarap", "tps", m=200, seed=0, cache=False, progress=False)

    runs = [("fixed", fixed)]
    for _ in range(rounds):
        runs += [("joint", None), ("fixed", fixed)]
    ref, rows = None, []
    for kind, run in runs:
        if kind == "joint":
            run = functools.partial(train_within, shape, pr, ref, seed=0, cache=False, progress=False)
        (op, rec), cpu, st, tal, load = staged(acc, run)
        ref = rec if kind == "fixed" and ref is None else ref
        rows.append((kind, rec, cpu, st, tal, load))
        stages = {k: v for k, v in st.items() if not k.startswith(("n ", "w ", "K "))}
        fit = rec.fit_cpu_seconds if kind == "joint" else rec.stage_times.get("fit", 0) + rec.stage_times.get("fold", 0)
        fitw = rec.budget["fit"] if kind == "joint" else 0.0
        m = len(rec.idx) if kind == "joint" else len(rec.samples)
        print(
            f"{kind} m={m}: {cpu:.2f} CPU s, work {tal.total + fitw:.4e} (factorisations {tal.factor:.4e}, "
            f"{sum(st.get('n ' + k, 0) for k in stages if k.startswith('factorisation')):.0f} of them; setup "
            f"{sum(tal.setups.values()):.4e} over {len(tal.setups)} solvers; fit {fitw:.4e}); fit CPU {fit:.2f}; "
            f"load average {load[0]:.2f} -> {load[1]:.2f}",
            flush=True,
        )
        for k in sorted(stages):
            print(
                f"    {k:32s} {stages[k]:7.2f} CPU s  {st['n ' + k]:6.0f} calls  work {st['w ' + k]:.4e}  "
                f"K nonzeros {st.get('K ' + k, 0):.4e}"
            )
        print(f"    {'other (Python, assembly, fit)':32s} {cpu - sum(stages.values()):7.2f} CPU s")
    fx = [r for r in rows if r[0] == "fixed"]
    fixed_cpu = [r[2] for r in fx]
    for kind, rec, cpu, _, _, load in rows:
        if kind == "joint":
            w = (rec.work + rec.budget["fit"]) / ref.work
            print(
                f"joint m={len(rec.idx)} ({rec.budget['solved']} solved): work {w:.2f}x; CPU {cpu / fixed_cpu[0]:.2f}x "
                f"the first fixed-P, {cpu / np.mean(fixed_cpu):.2f}x their mean "
                f"({', '.join(f'{c:.2f}' for c in fixed_cpu)} CPU s); load average {load[0]:.2f} -> {load[1]:.2f}"
            )


if __name__ == "__main__":
    warnings.simplefilter("ignore")
    mode, name, size, radius, count = sys.argv[1:6]
    {"split": split, "budget": budget, "within": within}[mode](name, int(size), float(radius), int(count))
