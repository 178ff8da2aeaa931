"""One inertia-shift policy (issue 35 §3): the kink code's old mean-based shift against the median-based one.

The held set's Newton direction (:func:`defop.variational.newton.kink_active_set`, the pull of
:func:`defop.variational.kink.kink_pull`), check 4's bound (:func:`defop.variational.kink.kink_gap`) and the kink
certificate's decrement and inertia (:func:`defop.variational.kink.newton_decrement`) used to shift the exact Hessian's
diagonal by ``INERTIA_SHIFT`` · mean|diag| (``old``); they now share check 5's
:func:`defop.variational.inertia.inertia_shift` (``new``: ``INERTIA_SHIFT`` · median|diag|, bounded). In the kink code
the shift regularises a Newton direction, so a smaller one changes which held elements are released.

Every training sample of a shape (``sample_shape`` with the seed :func:`defop.train` uses, S-ARAP) is solved under both
policies from the same start, the rest pose (:meth:`Solver.solve_best`, the bootstrap solves of training), one sample
at a time, old then new (so both see the same machine load), single-threaded BLAS. Per sample: energy difference
(relative), the largest vertex displacement between the two minima (fraction of the bounding-box diagonal),
Newton iterations, CPU seconds, triangles released from the kink, and whether both verified. A minimum *moved* when
|ΔE|/E > ``--energy-tol`` (1e-10) or the displacement > ``--disp-tol`` (1e-9 of the diagonal).

Run: ``python benchmarks/bench_inertia_shift.py [--shapes aleph bar u_shape] [--samples 200]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

from defop.variational import kink, newton
from defop.variational.inertia import INERTIA_SHIFT, inertia_shift


def old_shift(solver, data):
    """The kink code's shift before solver VERSION 6: ``INERTIA_SHIFT`` of the mean |diagonal|."""
    return INERTIA_SHIFT


@contextlib.contextmanager
def policy(name):
    """The kink code (newton.kink_active_set, kink.kink_gap, kink.newton_decrement) under ``old`` or ``new``;
    check 5 (verify.verify_point) keeps the median policy under both, as it did before."""
    fn = old_shift if name == "old" else inertia_shift
    saved = newton.inertia_shift, kink.inertia_shift
    newton.inertia_shift = kink.inertia_shift = fn
    try:
        yield
    finally:
        newton.inertia_shift, kink.inertia_shift = saved


def released(reason):
    """Triangles released from the kink, summed over the held stages a solve's reason reports."""
    return sum(int(k) for k in re.findall(r"(\d+) triangle\(s\) released", reason))


def direction(solver, X):
    """The held set's Newton direction at X under both shifts (what :func:`kink_active_set` computes there).

    Returns (held elements, new/old absolute shift, ‖p_new − p_old‖/‖p_new‖, λ²/2 / E old, new, pull gain / E old,
    new): the pull gain decides the releases (a release when it exceeds tol · E)."""
    hold = np.full(len(solver.mesh.F), solver._kink)
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=hold)
    gf = g[solver.free]
    held = int(kink.held_on_kink(solver, X, hold)[3].sum())
    out = []
    for shift in (old_shift(solver, data), inertia_shift(solver, data)):
        p = solver.newton_direction(gf, data, rel_shift=shift)
        out.append((p, -float(gf @ p) / 2 / E, kink.kink_pull(solver, X, local, p, hold)[0] / E))
    (po, do, go), (pn, dn, gn) = out
    ratio = inertia_shift(solver, data) / old_shift(solver, data)
    return held, ratio, float(np.linalg.norm(pn - po) / max(np.linalg.norm(pn), 1e-300)), do, dn, go, gn


def solve(solver, T, name):
    with policy(name), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        r = solver.solve_best(T)
        cpu = time.process_time() - c0
    return r, cpu


def samples_of(case, m, seed):
    """(shape, Q (k, n, 2), what): the training samples of a shape, or ``bar_fig10``: Fig. 10's grid (17 x 17
    positions of the bar's handle within 0.3 of its rest position, notebook 08)."""
    import defop as dop
    from defop.analysis.trajectories import handle_grid
    from defop.training.sampling import sample_shape

    if case == "bar_fig10":
        shape = dop.shapes.load("bar")
        grid = handle_grid(shape.P_moving[0], 0.3, 17)
        xs, ys = np.meshgrid(grid.xs, grid.ys)
        Q = (grid.center + np.stack([xs.ravel(), ys.ravel()], axis=1))[:, None, :]
        return shape, Q, "Fig. 10's 17 x 17 grid"
    shape = dop.shapes.load(case)
    return shape, sample_shape(shape, m, np.random.default_rng(seed)), f"{m} training samples (seed {seed})"


def compare(case, m, seed, energy_tol, disp_tol, verbose):
    """Both policies on every sample of one case; prints a row per sample and a summary."""
    import defop as dop

    shape, Q, what = samples_of(case, m, seed)
    shape_name, m = case, len(Q)
    diag = shape.mesh.bbox_diagonal
    solver = dop.variational.Solver(shape.mesh, shape.handles, "sarap")
    print(
        f"\n{shape_name}: {shape.mesh.n_vertices} vertices, {len(shape.mesh.F)} triangles, S-ARAP at {what}, "
        f"start: rest; load average {os.getloadavg()[0]:.1f}"
    )
    if verbose:
        print(
            f"{'k':>4s} {'ΔE/E':>10s} {'|ΔX|/diag':>10s} {'it old':>6s} {'it new':>6s} {'CPU old':>8s} "
            f"{'CPU new':>8s} {'rel old':>7s} {'rel new':>7s} {'ok':>3s} {'held':>5s} {'shift':>7s} {'Δp':>8s} "
            f"{'gain old':>9s} {'gain new':>9s}"
        )
    rows = []
    for k, q in enumerate(Q):
        T = shape.targets(q)
        (a, ca), (b, cb) = solve(solver, T, "old"), solve(solver, T, "new")
        dE = (b.energy - a.energy) / abs(a.energy)
        dX = float(np.abs(b.X - a.X).max()) / diag
        held, ratio, dp, _, _, go, gn = direction(solver, b.X)
        row = (dE, dX, a.iterations, b.iterations, ca, cb, released(a.reason), released(b.reason))
        rows.append((*row, a.converged and b.converged, held, ratio, dp, go, gn))
        if verbose:
            print(
                f"{k:4d} {dE:+10.2e} {dX:10.2e} {row[2]:6d} {row[3]:6d} {ca:8.2f} {cb:8.2f} {row[6]:7d} "
                f"{row[7]:7d} {int(a.converged)}{int(b.converged)} {held:5d} {ratio:7.1e} {dp:8.1e} {go:9.1e} "
                f"{gn:9.1e}",
                flush=True,
            )
    dE, dX, ia, ib, ca, cb, ra, rb, ok, held, ratio, dp, go, gn = (np.array(c) for c in zip(*rows))
    moved = np.flatnonzero((np.abs(dE) > energy_tol) | (dX > disp_tol))
    tol = solver.verify_tol
    print(
        f"{shape_name} summary: both verified {ok.sum()}/{m}; |ΔE|/E max {np.abs(dE).max():.2e} "
        f"(new lower in {np.count_nonzero(dE < -energy_tol)}, higher in {np.count_nonzero(dE > energy_tol)} beyond "
        f"{energy_tol:g}); |ΔX|/diag max {dX.max():.2e}, median {np.median(dX):.2e}; moved (ΔE > {energy_tol:g} or "
        f"ΔX > {disp_tol:g}): {len(moved)} samples {moved[:12].tolist()}{' ...' if len(moved) > 12 else ''}"
    )
    print(
        f"{shape_name} cost: Newton iterations old {ia.sum()} new {ib.sum()} (per sample differs in "
        f"{np.count_nonzero(ia != ib)}); CPU s old {ca.sum():.1f} new {cb.sum():.1f} "
        f"(ratio {cb.sum() / ca.sum():.3f}); kink releases old {ra.sum()} new {rb.sum()} "
        f"(differs in {np.count_nonzero(ra != rb)} samples); load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"{shape_name} kink direction at the new minima: held elements median {np.median(held):.0f}, max {held.max()}; "
        f"new/old shift median {np.median(ratio):.1e}, min {ratio.min():.1e}; ‖Δp‖/‖p‖ median {np.median(dp):.1e}, "
        f"max {dp.max():.1e}; pull gain/E > tol ({tol:g}) old {np.count_nonzero(go > tol)}, new "
        f"{np.count_nonzero(gn > tol)}; max gain/E old {go.max():.1e}, new {gn.max():.1e}"
    )
    return len(moved)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="*", default=["aleph", "bar", "u_shape"])
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0, help="the sampling seed (dop.train's default is 0)")
    parser.add_argument("--energy-tol", type=float, default=1e-10)
    parser.add_argument("--disp-tol", type=float, default=1e-9)
    parser.add_argument("--quiet", action="store_true", help="summaries only, no row per sample")
    a = parser.parse_args()
    t0 = time.perf_counter()
    with threadpool_limits(1):
        moved = {s: compare(s, a.samples, a.seed, a.energy_tol, a.disp_tol, not a.quiet) for s in a.shapes}
    print(
        f"\nsamples whose minimum moved: {moved} ({time.perf_counter() - t0:.0f} s, "
        f"load average {os.getloadavg()[0]:.1f})"
    )
