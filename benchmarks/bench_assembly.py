"""Cheaper Newton iterations (issues 15, 36): the fused numba kernels against the numpy closed forms, per iteration.

One Newton iteration of the S-ARAP solver is: the element work (E, ∇E, per-element eigensystems, assembly into the
fixed CSC pattern: ``ReducedProblem.grad_hess``), one factorisation and solve, and the line search's energies. The
numpy path (``kernel="numpy"``, the reference) does the element work in about 70 numpy calls; the fused kernels
(:mod:`defop.variational.fused`, the default) in one loop over the elements. Per shape (bar, U, aleph; bar_3d in
3D), one BLAS thread, CPU seconds (``time.process_time``), median of ``--repeats``:

* the parts, at a solved configuration: element work with each kernel, one energy evaluation with each, one
  factorisation + solve (qdldl in 2D; ``auto``'s back end in 3D);
* whole solves: ``--samples`` verified S-ARAP solves from the rest pose with each kernel, CPU per Newton iteration
  (total CPU over the iterations, continuation and verification included), and whether both kernels reach the same
  minima (largest relative energy difference, largest vertex distance over the bounding-box diagonal).

Run: ``python benchmarks/bench_assembly.py [--shapes bar u_shape aleph bar_3d] [--samples 4]``.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def _cpu_ms(f, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.process_time()
        f()
        out.append(time.process_time() - t0)
    return 1e3 * float(np.median(out))


def parts(solver, X, repeats):
    """CPU ms of the element work and one energy evaluation per kernel, and of one factorisation + solve."""
    row = {}
    for k in ("numpy", "numba"):
        solver.kernel = k
        solver.grad_hess(X, 1e-5)  # warm: compiled kernels, slot map
        row[f"grad_hess {k}"] = _cpu_ms(lambda: solver.grad_hess(X, 1e-5), repeats)
        row[f"energy {k}"] = _cpu_ms(lambda: solver.energies(X, 1e-5), repeats)
    _, g, data, _ = solver.grad_hess(X, 1e-5)
    gf = g[solver.free]
    solver.newton_direction(gf, data)
    row["factor+solve"] = _cpu_ms(lambda: solver.newton_direction(gf, data), repeats)
    return row


def solves(shape, Qs, kernel):
    """Verified solves of the samples with one kernel: (CPU s, Newton iterations, results)."""
    import defop as dop

    solver = dop.variational.Solver(shape.mesh, shape.handles, "sarap")
    solver.kernel = kernel
    solver.solve(shape.targets(Qs[0]))  # warm: factorisation's symbolic analysis, compiled kernels
    t0 = time.process_time()
    res = [solver.solve(shape.targets(Q)) for Q in Qs]
    return time.process_time() - t0, sum(r.iterations for r in res), res


def one(name, n_samples, repeats):
    import defop as dop

    shape = dop.shapes.load(name)
    Qs = dop.training.sampling.sample_shape(shape, n_samples + 1, np.random.default_rng(0))
    solver = dop.variational.Solver(shape.mesh, shape.handles, "sarap")
    X = solver.solve(shape.targets(Qs[0])).X
    row = parts(solver, X, repeats)
    runs = {k: solves(shape, Qs, k) for k in ("numpy", "numba")}
    (c0, i0, r0), (c1, i1, r1) = runs["numpy"], runs["numba"]
    dE = max(abs(a.energy - b.energy) / max(a.energy, 1e-12) for a, b in zip(r0, r1))
    dX = max(float(np.abs(a.X - b.X).max()) for a, b in zip(r0, r1)) / shape.mesh.bbox_diagonal
    ok = all(a.converged and b.converged for a, b in zip(r0, r1))
    print(
        f"{name:>9} {shape.mesh.n_vertices:6d} v {solver.hessian.backend:>7}: element work "
        f"{row['grad_hess numpy']:6.2f}"
        f" -> {row['grad_hess numba']:5.2f} ms ({row['grad_hess numpy'] / row['grad_hess numba']:4.1f}x), energy "
        f"{row['energy numpy']:5.2f} -> {row['energy numba']:5.2f} ms, factor+solve {row['factor+solve']:6.2f} ms | "
        f"per iteration {1e3 * c0 / i0:6.2f} -> {1e3 * c1 / i1:6.2f} ms ({c0 / i0 / (c1 / i1):4.2f}x; iterations "
        f"{i0}/{i1}); verified {ok}; same minima: dE/E {dE:.1e}, dX/diag {dX:.1e}",
        flush=True,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", nargs="+", default=["bar", "u_shape", "aleph", "bar_3d"])
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    from threadpoolctl import threadpool_limits

    warnings.simplefilter("ignore")
    print(
        f"S-ARAP Newton iteration, numpy -> fused numba kernels; one BLAS thread; CPU ms (median of {args.repeats}); "
        f"{time.strftime('%Y-%m-%d %H:%M')}, load average {os.getloadavg()[0]:.1f}"
    )
    with threadpool_limits(limits=1):
        for name in args.shapes:
            one(name, args.samples, args.repeats)
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
