"""Adaptive sampling benchmark (issue 28, part 2): held-out error against the number of solved samples, uniform and
adaptive, side by side in one run.

For the 2D aleph and the 2D octopus (S-ARAP, TPS Ψ, hat Φ): the (8a)/n over N = 100 held-out samples
(``dop.training.held_out``, seed 5000, solved from the rest pose) of

* **uniform**: ``dop.train(m=500, seed=0, rounds=1)``, and the fits to its first m samples (with one round each
  prefix is exactly what ``train(samples=Q[:m], rounds=1)`` solves: the linear bootstrap uses the first dn + 1);
* **adaptive**: ``dop.training.train_adaptive(m=167)`` with its defaults (halves' disagreement, a pool of
  3(m - n_initial)) and with a pool of 2,000 for each criterion (disagreement, energy residual), and the fit after
  its initial set and each batch.

Prints both curves, the number of adaptive samples that reaches the error of 500 uniform ones (log-log
interpolation between stages; "not reached" if none does) and the ratio 500 / that, with the load average and the
CPU seconds of the process. Target: the error of 500 uniform samples with at most 167 adaptive samples (ratio >= 3).
Run: ``DEFOP_CACHE=... python benchmarks/bench_adaptive.py [aleph] [octopus]`` (the cache makes reruns cheap).
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

import defop as dop
from defop.analysis.metrics import approximation_error
from defop.operator.fit import fit

UNIFORM, ADAPTIVE = 500, 167
COUNTS = [50, 100, 167, 250, 333, 500]
#: (criterion, pool) of each adaptive run: the default (pool 3(m - n_initial)) and a large pool per criterion
CONFIGS = (("disagreement", None), ("disagreement", 2000), ("residual", 2000))


def _prefix_errors(shape, samples, X, counts, Q_test, X_test):
    """(8a)/n over the held-out set of the TPS fit to the first c samples, for each c."""
    out = []
    for c in counts:
        op = fit(shape.mesh, shape.handles, shape.moving, samples[:c], X[:c], "tps", "hat")
        out.append(approximation_error(op, Q_test, X_test))
    return np.array(out)


def samples_at(counts, errors, target):
    """The sample count at which a decreasing error curve first reaches ``target`` (log-log interpolation), or None."""
    for i, e in enumerate(errors):
        if e <= target:
            if i == 0:
                return float(counts[0])
            lc, le = np.log(counts[i - 1 : i + 1]), np.log(errors[i - 1 : i + 1])
            return float(np.exp(np.interp(np.log(target), le[::-1], lc[::-1])))
    return None


def run(name, n_jobs=1):
    shape = dop.shapes.load(name)
    t0 = time.perf_counter()
    _, uni = dop.train(shape, "sarap", "tps", m=UNIFORM, seed=0, rounds=1, n_jobs=n_jobs, progress=False)
    Q_test, X_test, ok = dop.training.held_out(shape, "sarap", 100, seed=5000, n_jobs=n_jobs, progress=False)
    e_uni = _prefix_errors(shape, uni.samples, uni.X, COUNTS, Q_test, X_test)
    print(
        f"\n{name}: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles, S-ARAP, TPS, hat Φ; "
        f"uniform ({uni.cache}, {time.perf_counter() - t0:.0f} s), every sample converged "
        f"{bool(uni.converged.all())}, held-out {bool(ok.all())}"
    )
    return [_adaptive(shape, crit, pool, e_uni, Q_test, X_test, n_jobs) for crit, pool in CONFIGS]


def _adaptive(shape, criterion, pool, e_uni, Q_test, X_test, n_jobs):
    t1 = time.perf_counter()
    _, ada = dop.training.train_adaptive(
        shape, "sarap", "tps", m=ADAPTIVE, seed=0, criterion=criterion, pool=pool, n_jobs=n_jobs, progress=False
    )
    t2 = time.perf_counter()
    counts = ada.params["counts"]
    e_ada = _prefix_errors(shape, ada.samples, ada.X, counts, Q_test, X_test)
    print(
        f"adaptive, criterion {criterion!r} (initial {counts[0]}, batches of {ada.params['batch']} from a pool of "
        f"{ada.params['pool']}, {t2 - t1:.0f} s, every sample converged {bool(ada.converged.all())}): "
        f"(8a)/n over N = 100"
    )
    print("  uniform m  error        adaptive m  error")
    for i in range(max(len(COUNTS), len(counts))):
        left = f"  {COUNTS[i]:9d}  {e_uni[i]:.4e}" if i < len(COUNTS) else " " * 24
        right = f"   {counts[i]:10d}  {e_ada[i]:.4e}" if i < len(counts) else ""
        print(left + right)
    target = e_uni[-1]
    at = samples_at(counts, e_ada, target)
    uni_at = samples_at(COUNTS, e_uni, e_ada[-1])
    print(
        f"error of {UNIFORM} uniform: {target:.4e}; of {counts[-1]} adaptive: {e_ada[-1]:.4e} "
        f"({e_ada[-1] / target:.2f}x)"
    )
    if at is None:
        print(
            f"  adaptive does NOT reach it with {counts[-1]} samples; uniform reaches the adaptive "
            f"{counts[-1]}'s error at m = {uni_at if uni_at is None else round(uni_at)} "
            f"(ratio at equal error {'n/a' if uni_at is None else f'{uni_at / counts[-1]:.2f}'})"
        )
    else:
        print(
            f"  adaptive reaches it at m = {at:.0f}: ratio of samples at equal error {UNIFORM / at:.2f} (target >= 3)"
        )
    return at is not None and UNIFORM / at >= 3


def main(names):
    c0 = os.times()
    ok = [any(run(n)) for n in names]
    c1 = os.times()
    cpu = c1.user + c1.system + c1.children_user + c1.children_system - sum(c0[:4])
    print(f"\nload average {os.getloadavg()[0]:.2f}; CPU {cpu:.0f} s; DEFOP_CACHE={os.environ.get('DEFOP_CACHE')}")
    return all(ok)


if __name__ == "__main__":
    sys.exit(0 if main(sys.argv[1:] or ["aleph", "octopus"]) else 1)
