"""Multilevel training against the one-level policy (issue 36): CPU seconds of ``train()`` and the same ground truth.

For each policy, ``dop.train(shape, "sarap", "tps", m, seed=0, policy=...)`` runs from an empty ``DEFOP_CACHE`` of
its own (imports and the shape's meshing outside the timed span); the CPU seconds of the process tree (this process
and joblib's workers, polled by psutil) and the wall time are printed with the load average. Then the samples are
compared one by one with a reference: a ``--reference`` file written by ``--save`` on another commit (main's
policy), else the first policy of the run. A sample *changed* when its S-ARAP energy differs by more than 1e-6
relative, measured against max(E_ref, 1e-3 × the median reference energy); every changed sample is printed. The
target: at most 2 in 200 higher by more than 1e-6 and none higher by 1%.

    python benchmarks/bench_multilevel.py --shape aleph --m 200 --policies full multilevel
    python benchmarks/bench_multilevel.py --shape aleph --save /tmp/ref_aleph.npz --policies full   # on main
    python benchmarks/bench_multilevel.py --shape aleph --reference /tmp/ref_aleph.npz --policies multilevel
    python benchmarks/bench_multilevel.py --shape aleph --n-vertices 12000 --m 40 --policies full multilevel

``--round2 M`` measures round 2 alone on M samples in one process: re-solving the current solution (main) against
verifying it (this branch), in CPU s and Newton solves (calls of ``ReducedHessian.solve``), and compares the minima.

``--held-out N`` adds the paper's (8a)/n over N held-out samples (``dop.training.held_out``, seed 5000, main's full
policy, outside the timed span) for each operator.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time

import numpy as np

REL = 1e-6
BIG = 1e-2


class TreeCPU:
    """CPU seconds (user + system) of this process and its children since entering, polled every 0.5 s."""

    def __init__(self):
        import psutil

        self.me = psutil.Process()
        self.base, self.cpu = {}, {}
        self.stop = threading.Event()
        for p in self._procs():
            self.base[p.pid] = self._read(p)
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _procs(self):
        return [self.me, *self.me.children(recursive=True)]

    @staticmethod
    def _read(p):
        import psutil

        try:
            return sum(p.cpu_times()[:2])
        except psutil.Error:
            return 0.0

    def _poll(self):
        for p in self._procs():
            v = self._read(p)
            if v:
                self.cpu[p.pid] = v

    def _run(self):
        while not self.stop.is_set():
            self._poll()
            self.stop.wait(0.5)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self._poll()

    @property
    def seconds(self):
        return sum(v - self.base.get(k, 0.0) for k, v in self.cpu.items())


def run_policy(shape, m, policy, n_jobs):
    """(record, CPU s, wall s, load before, load after) of one training from an empty cache."""
    import defop as dop

    os.environ["DEFOP_CACHE"] = tempfile.mkdtemp(prefix=f"bench-ml-{policy}-")
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    with TreeCPU() as cpu:
        op, rec = dop.train(shape, "sarap", "tps", m=m, seed=0, n_jobs=n_jobs, progress=False, policy=policy)
    return op, rec, cpu.seconds, time.perf_counter() - t0, load0, os.getloadavg()[0]


def energies(shape, X):
    from defop.variational.solver import Solver

    s = Solver(shape.mesh, shape.handles, "sarap")
    return np.array([s.energy_of(x) for x in X])


def compare(E, E_ref, conv, label):
    """Print every changed sample; return (higher by > REL, higher by > BIG)."""
    floor = 1e-3 * float(np.median(E_ref))
    rel = (E - E_ref) / np.maximum(E_ref, floor)
    changed = np.flatnonzero(np.abs(rel) > REL)
    for k in changed:
        print(f"    {label} sample {k:4d}: E = {E[k]:.6e} against {E_ref[k]:.6e} ({rel[k]:+.2e} relative)")
    hi, big = int((rel > REL).sum()), int((rel > BIG).sum())
    print(
        f"  {label}: {len(E)} samples, {int(conv.sum())} verified; changed {len(changed)}, higher by > {REL:g}: {hi}, "
        f"by > 1%: {big}; max relative {rel.max():+.2e}, min {rel.min():+.2e}"
    )
    return hi, big


def held_out_truth(shape, n, n_jobs):
    """N held-out samples and their ground truth (main's full policy, seed 5000), outside the timed spans."""
    import defop as dop

    os.environ["DEFOP_CACHE"] = tempfile.mkdtemp(prefix="bench-ml-held-out-")
    Q, X, _ = dop.training.held_out(shape, "sarap", n, seed=5000, n_jobs=n_jobs, progress=False)
    return Q, X


def round_two(shape, m):
    """Round 2 alone, one process: the incumbent re-solved (main) against verified (this branch)."""
    import warnings

    from defop.operator.fit import fit
    from defop.operator.handle_bases import basis_size
    from defop.training import batch
    from defop.training import bootstrap as bs
    from defop.training.sampling import sample_shape
    from defop.variational import problem

    warnings.simplefilter("ignore")
    os.environ["DEFOP_CACHE"] = "off"
    Q = sample_shape(shape, m, np.random.default_rng(0))
    X, _ = bs.solve_samples(shape, Q, n_jobs=1, progress=False)
    smooth = "quadratic" if m + 1 >= basis_size("quadratic", shape.n_moving, d=shape.mesh.dim) else "linear"
    W = batch.warm_starts(fit(shape.mesh, shape.handles, shape.moving, Q, X, smooth, "hat"), Q, shape.mesh, "sarap")
    count, real = [0], problem.ReducedHessian.solve

    def counted(self, *args, **kw):
        count[0] += 1
        return real(self, *args, **kw)

    problem.ReducedHessian.solve = counted
    out = []
    for kw in (dict(X0=[[x, w] for x, w in zip(X, W)]), dict(X0=W, incumbents=X)):
        t, count[0] = time.process_time(), 0
        Xr, c = bs.solve_samples(shape, Q, "sarap", n_jobs=1, progress=False, rest=False, **kw)
        out.append((time.process_time() - t, count[0], Xr, c))
    problem.ReducedHessian.solve = real
    (to, fo, Xo, co), (tn, fn, Xn, cn) = out
    Eo, En = energies(shape, Xo), energies(shape, Xn)
    rel = np.abs(En - Eo) / np.maximum(Eo, 1e-3 * np.median(Eo))
    dist = np.abs(Xn - Xo).max() / shape.mesh.bbox_diagonal
    print(
        f"round 2 alone, {m} samples, one process: re-solve {to:.1f} CPU s, {fo} Newton solves; verify {tn:.1f} CPU s, "
        f"{fn} Newton solves ({to / tn:.2f}x); verified {int(co.sum())} and {int(cn.sum())}; energies within "
        f"{rel.max():.1e}, {int((rel > REL).sum())} samples beyond {REL:g}; positions within {dist:.1e} of the diagonal"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", default="aleph")
    ap.add_argument("--n-vertices", type=int, default=None)
    ap.add_argument("--m", type=int, default=200)
    ap.add_argument("--n-jobs", type=int, default=2)
    ap.add_argument("--policies", nargs="+", default=["full", "multilevel"])
    ap.add_argument("--reference", default=None, help="an .npz written by --save (main's policy)")
    ap.add_argument("--save", default=None, help="write the first policy's samples, X and energies here")
    ap.add_argument("--held-out", type=int, default=0)
    ap.add_argument("--round2", type=int, default=0, help="measure round 2 alone on this many samples, then stop")
    a = ap.parse_args()

    import defop as dop

    shape = dop.shapes.load(a.shape, a.n_vertices)
    print(f"{a.shape}: {shape.mesh.n_vertices} vertices, m = {a.m}, n_jobs = {a.n_jobs}, S-ARAP, TPS")
    if a.round2:
        return round_two(shape, a.round2)
    ref = None
    if a.reference:
        z = np.load(a.reference)
        ref = ("reference", z["E"], z["samples"], z["cpu"])
        print(f"  reference {a.reference}: {float(z['cpu']):.1f} CPU s")
    truth = held_out_truth(shape, a.held_out, a.n_jobs) if a.held_out else None
    rows = []
    for policy in a.policies:
        op, rec, cpu, wall, l0, l1 = run_policy(shape, a.m, policy, a.n_jobs)
        E = energies(shape, rec.X)
        line = f"  {policy:10s} ran {rec.policy:10s}: {cpu:8.2f} CPU s, wall {wall:7.1f} s, load {l0:.1f} -> {l1:.1f}"
        if rec.policy == "multilevel":
            info = rec.multilevel
            fired = sum(1 for r in info["rule"] if r)
            its = np.array(info["iterations"])
            line += (
                f"; coarse {info['coarse_vertices']} vertices; safeguard fired {fired}/{len(E)} {rec.safeguard}; "
                f"fine-run iterations median {np.median(its[its > 0]) if (its > 0).any() else 0:.0f}, "
                f"max {its.max()}; stages { ({k: round(v, 1) for k, v in rec.stage_times.items()}) }"
            )
        print(line, flush=True)
        if a.save and not rows:
            np.savez(a.save, X=rec.X, conv=rec.converged, E=E, samples=rec.samples, cpu=cpu, wall=wall)
        if ref is None:
            ref = (policy, E, rec.samples, cpu)
        elif np.array_equal(ref[2], rec.samples):
            compare(E, ref[1], rec.converged, f"{policy} against {ref[0]}")
            print(f"  CPU ratio {ref[0]} / {policy}: {ref[3] / cpu:.2f}x")
        if truth is not None:
            from defop.analysis.metrics import approximation_error

            print(f"  {policy} held-out (8a)/n over N = {a.held_out}: {approximation_error(op, *truth):.3e}")
        rows.append((policy, cpu))
    print(f"load average at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
