"""Where the time of one compressed DefOp frame goes, beside its floor and biharmonic coordinates (issue 28, part 5).

Aleph, S-ARAP, TPS-500 (``dop.train(..., m=500, seed=0, rounds=1)``, through ``DEFOP_CACHE`` when set),
``op.compress()`` at the default tolerance (``compress.TOL``), and at 1e-3 (the default before) for the record.
Prints, in one run, one BLAS thread, CPU time of this thread (``time.thread_time``: other jobs on the shared
machine preempt the process but do not add to it):

* the (8a) error over 100 held-out S-ARAP samples (seed 12345), exact and compressed (target: at most +1%);
* the frame time of biharmonic coordinates, of ``op(Q)`` (validated), ``evaluate_fast`` and, for the record,
  the numpy paths they replaced (the checked path ``op(Q)`` took before, and the numpy single frame);
* the breakdown: ψ, δψ A', t B, x + u and the handles, and the Python around them, for the numpy path and
  for the compiled kernel (:mod:`defop.operator.kernels`);
* the floor: the factors' bytes over this machine's copy bandwidth (a large numpy copy) plus ψ.

Target: ``op(Q)`` ≤ 1.5x biharmonic coordinates. Run: ``python benchmarks/bench_frame.py [m]``.
"""

from __future__ import annotations

import copy
import os
import sys
import time
import warnings

import numpy as np
from threadpoolctl import threadpool_limits

import defop as dop
from defop.analysis.metrics import approximation_error, copy_bandwidth
from defop.operator import kernels
from defop.rivals import peers

N_HELD_OUT = 100
OTHER_TOL = 1e-3  # the default before compress.TOL = 5e-3


def best_time(f, args, repeats=9, number=400):
    """Best CPU seconds per call of f(*a) over ``repeats`` runs cycling through ``args`` (``number`` calls each)."""
    runs = []
    for _ in range(repeats):
        t0 = time.thread_time()
        for i in range(number):
            f(*args[i % len(args)])
        runs.append((time.thread_time() - t0) / number)
    return min(runs), float(np.median(runs))


def cache_bandwidth(nbytes, repeats=9, number=200):
    """Bytes per CPU second, for ``nbytes`` (the factors' size: they stay in cache): a numpy copy (read +
    written) and a read alone (BLAS sdot of the buffer with itself)."""
    src = np.ones(nbytes // 4, np.float32)
    dst = np.empty_like(src)
    copy_bw = 2.0 * src.nbytes / best_time(lambda: np.copyto(dst, src), [()], repeats, number)[0]
    read_bw = src.nbytes / best_time(lambda: np.dot(src, src), [()], repeats, number)[0]
    return copy_bw, read_bw


def numpy_frame(op, f, Q):
    """The numpy single frame that ``evaluate_fast`` used before the kernel (for the record)."""
    dz = (Q - op.P).ravel()
    zz = np.vdot(dz, dz)
    y = op.handle_basis.delta_raw(dz, zz, np.empty(op._q, f["dtype"]))
    for M in f["mats"]:
        y = np.dot(y, M)
    out = y.astype(np.float64)
    out += op._x
    out[op._hcols] = f["xh"] + dz
    return out.reshape(-1, op.d)


def breakdown(op, Q):
    """Seconds of each step of a frame (best), the numpy path and the kernel."""
    f = op._fast_state()
    hb, k = op.handle_basis, f["kernel"]
    A32, B = k["A"], k["B"]
    Af = f["mats"][0]
    cm, czeps, inv_s2, ell0, log_kernel = k["tps"]
    dzs = [((q - op.P).ravel(),) for q in Q]
    zzs = [(d, d @ d) for (d,) in dzs]
    y = np.empty(op._q, np.float32)
    ys = [(hb.delta_raw(d, z, np.empty(op._q, np.float32)),) for d, z in zzs]
    ts = [(np.dot(yy, Af),) for (yy,) in ys]
    us = [(np.dot(t, B),) for (t,) in ts]
    out = np.empty(B.shape[1])
    empty = np.empty((0, 0), np.float32)
    xh = f["xh"]
    steps = {
        "numpy: Q − P and |Q − P|²": (lambda q: np.vdot(d := (q - op.P).ravel(), d), [(q,) for q in Q]),
        "numpy: ψ (delta_raw: gemv, 2 adds, log, product, subtract)": (lambda d, z: hb.delta_raw(d, z, y), zzs),
        "numpy: δψ A' (sgemv)": (lambda yy: np.dot(yy, Af), ys),
        "numpy: t B (sgemv)": (lambda t: np.dot(t, B), ts),
        "numpy: x + u (cast, add)": (lambda u: np.add(u.astype(np.float64), op._x, out=out), us),
        "numpy: the handles' exact part": (lambda d: np.add(f["xh"], d, out=out[: d.size]), dzs),
        "kernel: ψ (tps_raw)": (lambda d, z: kernels.tps_raw(d, z, cm, czeps, inv_s2, ell0, log_kernel, y), zzs),
        "kernel: δψ A', t B, x + u, handles (apply)": (
            lambda yy, d: kernels.apply(yy, A32, B, op._x, op._hcols, f["xh"], d),
            [(yy, d) for (yy,), (d,) in zip(ys, dzs)],
        ),
        "kernel: t B, x + u, handles (apply, A skipped)": (
            lambda t, d: kernels.apply(t, empty, B, op._x, op._hcols, f["xh"], d),
            [(t, d) for (t,), (d,) in zip(ts, dzs)],
        ),
        "kernel: the whole frame (tps_frame: dz, guard, ψ, apply)": (
            lambda q: kernels.tps_frame(q, op.P, f["R2"], k["far2"], *k["tps"], A32, B, op._x, op._hcols, xh),
            [(q,) for q in Q],
        ),
    }
    return {name: best_time(fn, args)[0] for name, (fn, args) in steps.items()}


def main(m=500):
    shape = dop.shapes.load("aleph")
    op, _ = dop.train(shape, "sarap", "tps", m=m, seed=0, rounds=1, progress=False)
    Qh, Xh, conv = dop.training.held_out(shape, "sarap", N_HELD_OUT, seed=12345, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        err = approximation_error(op, Qh, Xh)
        op.compress()
        err_c = approximation_error(op, Qh, Xh)
        other = copy.deepcopy(op).compress(tol=OTHER_TOL)
        err_o = approximation_error(other, Qh, Xh)
    Q = dop.training.sampling.sample_shape(shape, 50, np.random.default_rng(1))
    bih = peers.make_peer(shape, "biharmonic")
    f = op._fast_state()
    args = [(q,) for q in Q]
    methods = {
        "biharmonic coordinates (peer)": bih,
        "defop op(Q), compressed, validated (kernel)": op,
        "defop evaluate_fast, compressed (kernel)": op.evaluate_fast,
        f"defop op(Q), compress(tol={OTHER_TOL}) (kernel)": other,
        "before: op(Q) checked numpy path": lambda q: op._evaluate(q, fast=False),
        "before: evaluate_fast numpy path": lambda q: numpy_frame(op, f, q),
    }
    for q in Q[:3]:  # the kernel path and the numpy path agree to float32 round-off; handles exact
        assert np.abs(op(q) - numpy_frame(op, f, q)).max() < 1e-4 * shape.mesh.bbox_diagonal
        assert np.array_equal(op(q)[op.handles[op.moving]], q)
    with threadpool_limits(1):
        bw = copy_bandwidth()  # DRAM: a 256 MB copy
        cache_bw, read_bw = cache_bandwidth(op.factor_bytes())
    load0 = os.getloadavg()
    with threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for fn in methods.values():
            fn(Q[0])
        times = {name: [] for name in methods}
        for _ in range(3):  # interleaved rounds: each method sees the same load
            for name, fn in methods.items():
                times[name].append(best_time(fn, args, repeats=5))
        steps = breakdown(op, Q)
    load1 = os.getloadavg()
    best = {name: min(b for b, _ in t) for name, t in times.items()}
    med = {name: float(np.median([md for _, md in t])) for name, t in times.items()}
    bih_t = best["biharmonic coordinates (peer)"]
    nbytes = op.factor_bytes()
    psi = steps["kernel: ψ (tps_raw)"]
    print(
        f"\naleph: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles, S-ARAP, TPS-{m} "
        f"(|Ψ| = {op.handle_basis.size}), compress() default tol: rank {op.rank} {op.factors[1].dtype}, "
        f"{nbytes / 1e6:.2f} MB of factors; one BLAS thread, thread CPU time; load average "
        f"{load0[0]:.1f} before, {load1[0]:.1f} after; copy bandwidth {bw / 1e9:.1f} GB/s"
    )
    print(
        f"(8a)/n over {N_HELD_OUT} held-out S-ARAP samples ({int(conv.sum())} converged): exact {err:.4e}, "
        f"compressed {err_c:.4e} (+{100 * (err_c / err - 1):.3f}%, target <= +1%)"
    )
    print(
        f"compress(tol={OTHER_TOL}): rank {other.rank}, {other.factor_bytes() / 1e6:.2f} MB, (8a)/n {err_o:.4e} "
        f"(+{100 * (err_o / err - 1):.3f}%)"
    )
    print(f"\n{'frame':48s} {'best':>9s} {'median':>9s} {'/ biharmonic':>13s}")
    for name in methods:
        print(f"{name:48s} {1e6 * best[name]:6.1f} µs {1e6 * med[name]:6.1f} µs {best[name] / bih_t:12.2f}x")
    floor = nbytes / cache_bw + psi  # the factors are read once per frame, from cache
    floor_read = nbytes / read_bw + psi
    floor_dram = nbytes / bw + psi
    print(f"\nbreakdown (best of each step alone, {len(Q)} frames cycled):")
    for name, s in steps.items():
        print(f"  {name:58s} {1e6 * s:6.1f} µs")
    ours = best["defop op(Q), compressed, validated (kernel)"]
    around = ours - steps["kernel: the whole frame (tps_frame: dz, guard, ψ, apply)"]
    print(f"  {'Python around the kernel (op(Q) − tps_frame)':58s} {1e6 * around:6.1f} µs")
    print(
        f"floor: {nbytes / 1e6:.2f} MB / {cache_bw / 1e9:.0f} GB/s (a copy of that size, in cache) + ψ {1e6 * psi:.1f} "
        f"µs = {1e6 * floor:.1f} µs ({floor / bih_t:.2f}x biharmonic); / {read_bw / 1e9:.0f} GB/s (a read alone, sdot) "
        f"+ ψ = {1e6 * floor_read:.1f} µs ({floor_read / bih_t:.2f}x); from DRAM ({bw / 1e9:.1f} GB/s, a 256 MB copy): "
        f"{1e6 * floor_dram:.1f} µs; t B alone (BLAS sgemv, B in cache): {1e6 * steps['numpy: t B (sgemv)']:.1f} µs"
    )
    ratio = ours / bih_t
    print(
        f"\nop(Q) / biharmonic coordinates: {ratio:.2f}x (target <= 1.5x); floor / biharmonic {floor / bih_t:.2f}x "
        f"(copy), {floor_read / bih_t:.2f}x (read)"
    )
    return ratio <= 1.5 and err_c <= 1.01 * err


if __name__ == "__main__":
    sys.exit(0 if main(*(int(a) for a in sys.argv[1:])) else 1)
