"""Fewer factorisations per sample (issue 28 §1): candidate Newton policies against main's, on the same samples.

Every policy solves the same S-ARAP samples of a shape (``defop.training.sampling.sample_shape``, fixed seed) with a
local verified solve (:meth:`defop.variational.solver.Solver.solve`) from the same start: the rest pose, or with
``--start bootstrap`` a bootstrap operator's prediction (a DefOp trained on ``--bootstrap`` other samples, as the
second round of training does). Policies:

* ``main``: main's solver (one fresh LDLᵀ per Newton step, μ stages ``(1e-5, 0)``);
* ``pcg``: inexact Newton. The last factorisation preconditions conjugate gradients on the new Hessian for the
  following Newton steps (relative residual ``--rtol``); it is refactorised only when PCG stalls (no convergence
  within ``--cg-iters`` iterations, or non-positive curvature). The verification (inertia) always factorises afresh;
* ``smoothed``: the μ stages ``(1e-5, 0)`` given explicitly (in 3D main's default is the held stage first,
  :data:`defop.variational.solver.SMOOTHING_3D`, with this schedule as its fallback);
* ``mu0``: no smoothing stage (``smoothing=(0,)``, no fallback): Eq. (11) at once, the kink held by the active set;
* ``pcg+mu0``: both.

Per policy: factorisations, PCG solves, Newton iterations, wall and CPU seconds, verified samples; then every sample
whose energy differs from main's by more than 1e-9 relative, and how. A policy is acceptable only if every sample is
verified (``converged``) and none ends on a higher-energy branch by more than 1e-6 relative.

Run: ``python benchmarks/bench_newton_policy.py [--shape aleph] [--samples 200] [--start rest|bootstrap]``.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np

from defop.variational.backend import pcg

#: the relative diagonal shift of a Newton step (ReducedProblem.newton_direction's default); the verification's
#: larger shift (INERTIA_SHIFT) always factorises afresh, so its inertia is exact
NEWTON_SHIFT = 1e-10


class Counted:
    """Wraps a solver's ``hessian.solve``: counts factorisations and, with ``maxiter`` > 0, re-uses the last
    Newton-step factorisation as a PCG preconditioner (the ``pcg`` policy)."""

    def __init__(self, solver, maxiter=0, rtol=1e-6):
        self.hessian = solver.hessian
        self.factor = solver.hessian.solve  # the bound method: one fresh factorisation per call
        self.maxiter, self.rtol = maxiter, rtol
        self.factorisations = self.pcg_solves = self.cg_iterations = 0
        self.ready = False
        solver.hessian.solve = self.solve

    def solve(self, data, b, rel_shift, reuse=0.0):
        """``ReducedHessian.solve`` under this policy (the library's own re-use, ``reuse``, stays off here)."""
        if self.maxiter and self.ready and rel_shift == NEWTON_SHIFT:
            K = self.hessian.matrix(data, rel_shift)
            found = pcg(K, b, self.hessian._factor.solve, self.rtol, self.maxiter)  # the library's PCG
            if found is not None:
                self.pcg_solves += 1
                self.cg_iterations += found[1]
                return found[0]
        self.factorisations += 1
        x = self.factor(data, b, rel_shift)
        self.ready = rel_shift == NEWTON_SHIFT  # a verification factorisation is never re-used
        return x


POLICIES = {"main": (0, None), "smoothed": (0, (1e-5,)), "pcg": (1, None), "mu0": (0, (0.0,)), "pcg+mu0": (1, (0.0,))}


def run(shape, targets, starts, policy, cg_iters, rtol):
    """Solve every sample under ``policy``: per-sample (energy, converged, iterations) and the totals."""
    from defop.variational import Solver

    use_pcg, smoothing = POLICIES[policy]
    solver = Solver(shape.mesh, shape.handles, "sarap", smoothing=smoothing)
    count = Counted(solver, cg_iters if use_pcg else 0, rtol)
    E, ok, iters = [], [], []
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for T, X0 in zip(targets, starts):
            count.ready = False  # no re-use across samples: the grouping stays independent of the workers
            r = solver.solve(T, X0=X0)
            E.append(r.energy)
            ok.append(r.converged)
            iters.append(r.iterations)
    totals = dict(
        wall=time.perf_counter() - t0,
        cpu=time.process_time() - c0,
        factorisations=count.factorisations,
        pcg=count.pcg_solves,
        cg=count.cg_iterations,
    )
    return np.array(E), np.array(ok), np.array(iters), totals


def bootstrap_starts(shape, Q, m, seed):
    """A TPS operator trained on ``m`` other samples (seed + 1) and its flip-free predictions at Q (None where not)."""
    import defop as dop

    op, _ = dop.train(shape, energy="sarap", basis="tps", m=m, seed=seed + 1, n_jobs=1, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        P = op(Q)
    return [None if np.any(shape.mesh.flipped(X)) else X for X in P]


def main(shape_name, n_vertices, samples, seed, start, m_boot, policies, cg_iters, rtol):
    import defop as dop
    from defop.training.sampling import sample_shape

    shape = dop.shapes.load(shape_name, n_vertices=n_vertices) if n_vertices else dop.shapes.load(shape_name)
    Q = sample_shape(shape, samples, np.random.default_rng(seed))
    targets = [shape.targets(q) for q in Q]
    starts = bootstrap_starts(shape, Q, m_boot, seed) if start == "bootstrap" else [None] * samples
    print(
        f"{shape_name}: {shape.mesh.n_vertices} vertices, {samples} S-ARAP samples (seed {seed}), start: {start}"
        + (f" (TPS on {m_boot} samples; {sum(s is None for s in starts)} flipped: rest)" if start != "rest" else "")
        + f"; PCG: ≤ {cg_iters} iterations to {rtol:g}; load average {os.getloadavg()[0]:.1f}"
    )
    head = f"{'policy':>8s} {'factor.':>8s} {'PCG':>6s} {'CG it':>6s} {'Newton':>7s} {'wall s':>8s} {'CPU s':>8s}"
    print(head + f" {'verified':>9s} {'ΔE > 1e-9':>10s} {'higher > 1e-6':>13s}")
    ref = None
    for policy in policies:
        E, ok, iters, t = run(shape, targets, starts, policy, cg_iters, rtol)
        ref = ref or (E, policy)
        rel = (E - ref[0]) / np.maximum(np.abs(ref[0]), 1e-300)
        changed = np.flatnonzero(np.abs(rel) > 1e-9)
        higher = np.flatnonzero(rel > 1e-6)
        print(
            f"{policy:>8s} {t['factorisations']:8d} {t['pcg']:6d} {t['cg']:6d} {iters.sum():7d} {t['wall']:8.2f} "
            f"{t['cpu']:8.2f} {ok.sum():5d}/{len(ok):<3d} {len(changed):10d} {len(higher):13d}"
        )
        if len(changed):
            print(
                f"{'':>10s} energy vs {ref[1]}: highest {rel.max():+.2e}, lowest {rel.min():+.2e} relative; "
                f"{np.count_nonzero(rel > 1e-9)} higher, {np.count_nonzero(rel < -1e-9)} lower by more than 1e-9; "
                f"{np.count_nonzero(rel > 1e-7)} higher by more than 1e-7"
            )
        for k in changed[:20]:
            print(f"{'':>10s} sample {k}: E = {E[k]:.12g} vs {ref[1]}'s {ref[0][k]:.12g} ({rel[k]:+.2e} relative)")
        if len(changed) > 20:
            print(f"{'':>10s} ... and {len(changed) - 20} more")
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", default="aleph")
    parser.add_argument("--n-vertices", type=int)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start", choices=("rest", "bootstrap"), default="rest")
    parser.add_argument("--bootstrap", type=int, default=50, help="samples of the bootstrap operator")
    parser.add_argument("--policies", nargs="*", default=list(POLICIES), choices=list(POLICIES))
    parser.add_argument("--cg-iters", type=int, default=10)
    parser.add_argument("--rtol", type=float, default=1e-6)
    a = parser.parse_args()
    main(a.shape, a.n_vertices, a.samples, a.seed, a.start, a.bootstrap, a.policies, a.cg_iters, a.rtol)
