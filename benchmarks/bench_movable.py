"""Handles that move at rest (issue 38): the joint operator D(x; P, Q) vs retraining, MLS and biharmonic coordinates.

Per shape (the aleph, all 5 handles movable; the octopus, 3 of its 9 movable): placement regions of radius 5% of the
bounding-box diagonal; held-out placements drawn uniformly over the region vertices, × ``N_Q`` configurations Q
each (the Q regions travel with P), truth from the verified solver (problem 6, from the rest pose). Printed, each
with its ratio and target:

* budget: CPU s of the joint training (sampling, solves, fit; no cache) over one fixed-P training at m = 200
  (``dop.train``, no cache), target <= 5x;
* error: mean (8a)/n per held-out frame of the joint operator (design A, TPS over (P, Q − P) with the correction),
  of the carried nominal operator (design B, :class:`defop.operator.movable.CarryOp`), of fixed-P operators
  retrained at each held-out placement (m = 200; target: joint <= 2x), and of MLS rigid, MLS similarity and
  biharmonic coordinates at the same (P, Q) (target: joint below each; biharmonic coordinates' per-placement
  precompute is printed);
* the largest handle residual before the correction (share of the diagonal), flipped triangles per frame (joint,
  carry, retrained);
* frame: the compressed joint frame (``evaluate_fast``, P as vertex indices and as points) over the compressed
  fixed-P frame, target <= 3x, beside the multiply-add floor (:func:`frame_cost`: the ratio of the two frames'
  multiply-adds, the logarithms of Ψ counted apart), at the shape's joint m and at m = 200 and 1,000
  (:func:`frame_table`).

Everything runs in this process (``DEFOP_N_JOBS=1``) so CPU seconds are this process's ``time.process_time()``.
Run: ``python benchmarks/bench_movable.py [--dim 3] [aleph] [octopus] [bar] [bar_3d] [octopus_3d] [n_placements]
[m_joint]`` (default the aleph and the octopus; ``--dim 3``: bar_3d, its end-face patch movable, and the tet octopus,
two arm tips movable, regions of 8% of the diagonal, ``BENCH_MOVABLE_VERTICES=n``: both meshed at about n vertices,
a reduced run printed as such; ``BENCH_MOVABLE_NO_TABLE=1``: no frame table); 10 placements, joint m 1500 on the
aleph, 800 on the octopus, 1000 on the bar, 540 on bar_3d, 800 on the tet octopus;
``python benchmarks/bench_movable.py frames [shapes]``: the frame table alone; ``BENCH_MOVABLE_NQ=5``: 5 Q per
training placement; ``BENCH_MOVABLE_TOL``: the joint operator's compression tolerance, default 5e-3 as the fixed-P
one; ``BENCH_MOVABLE_CENTRES``: its TPS centres, default all); fewer placements is a reduced run, printed as such.
Truth, retrained operators and the frame table's operators go through ``DEFOP_CACHE`` (their cost is not part of
any ratio); the two timed trainings never use the cache.
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

os.environ.setdefault("DEFOP_N_JOBS", "1")

import defop as dop  # noqa: E402
from defop.analysis import metrics  # noqa: E402
from defop.operator.movable import CarryOp, residual  # noqa: E402
from defop.rivals import peers  # noqa: E402
from defop.scene.placement import placement_regions  # noqa: E402
from defop.training.movable import sample_joint, shape_at, solve_joint, train_movable  # noqa: E402

N_Q = 10
FULL = 10
PEERS = ("mls-rigid", "mls-similarity", "biharmonic")


def err8a(mesh, X, T):
    """Mean (8a)/n per frame: Σ_v m_v |X − T|² / n_vertices, averaged over the frames (k, n_vertices, d)."""
    m = mesh.mass_matrix.diagonal()
    return float(np.mean(np.einsum("v,kvc->k", m, (X - T) ** 2)) / mesh.n_vertices)


def flips(mesh, X):
    return float(np.mean([np.count_nonzero(mesh.flipped(x)) for x in X]))


def frame_seconds(f, Qs):
    """(wall, CPU) best seconds per frame of ``f`` over the configurations Qs (:func:`metrics.repeat_timing`)."""
    t = metrics.repeat_timing(lambda: [f(q) for q in Qs], repeats=15, min_time=0.05)
    return t["best"] / len(Qs), t["cpu_best"] / len(Qs)


#: what one logarithm of Ψ costs in float32 multiply-adds of t B (numba, no SVML: 4.3 ns against 0.11 ns here)
LOG_MACS = 40


def frame_cost(op):
    """(multiply-adds, logarithms) of one compiled TPS frame of ``op`` (a compressed DefOp or MovableOp): the
    squared distances to the centres (dn × |centres|), δψ A' and t B (:func:`defop.operator.kernels.tps_frame`);
    the handles' correction (a few bumps) is left out."""
    k = op.fast_state().kernel
    cm = k.tps[0]
    return cm.size + k.A.size + k.B.size, cm.shape[1]


def frame_row(label, op0, opj, Qn, Q, P, V):
    """Time the compressed fixed-P frame (at Qn) and the joint frame (at Q, P as vertices and as points V[P]),
    one after the other (the same load), and print the ratios (wall and this thread's CPU time, the steadier on a
    busy machine) beside the multiply-add floor. Returns the wall ratio."""
    tf, cf = frame_seconds(op0.evaluate_fast, Qn)
    tj, cj = frame_seconds(lambda q: opj.evaluate_fast(q, P=P), Q)
    points = V[P]  # the same array each frame, as an editor's drag passes it
    tp, cp = frame_seconds(lambda q: opj.evaluate_fast(q, P=points), Q)
    (mf, lf), (mj, lj) = frame_cost(op0), frame_cost(opj)
    print(
        f"  {label}: fixed-P rank {op0.rank} {tf * 1e6:.1f} µs; joint |Ψ| {opj.basis.size} rank {opj.rank} "
        f"{tj * 1e6:.1f} µs (P as points {tp * 1e6:.1f} µs): ratio {tj / tf:.2f}x wall, {cj / cf:.2f}x CPU, P as "
        f"points {cp / cf:.2f}x CPU "
        f"(target <= 3x); floor {mj / mf:.2f}x multiply-adds ({mj} / {mf}), logs {lj} / {lf}, "
        f"{(mj + LOG_MACS * lj) / (mf + LOG_MACS * lf):.2f}x with a log as {LOG_MACS} multiply-adds; "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    return tj / tf


def case(name, movable):
    """The shape (at :data:`SIZES` vertices in 3D) and its placement regions (radius :data:`RADIUS` of the diagonal
    in 2D, :data:`RADIUS_3D` in 3D: a 3D handle is a patch, its region keeps only the vertices where the whole patch
    lands on vertices, fewer than a ball's)."""
    shape = dop.shapes.load(name, SIZES.get(name))
    mesh = shape.mesh
    frac = RADIUS_3D if mesh.dim == 3 else RADIUS
    return shape, placement_regions(shape, movable, radius=frac * mesh.bbox_diagonal)


def frame_table(name, movable=None, ms=(200, 1000), seed=0):
    """The compressed frame ratio at each joint m of ``ms`` against the fixed-P operator at m = 200 (trainings
    through the cache: only frames are timed). Returns {m: ratio}."""
    shape, pr = case(name, movable)
    mesh = shape.mesh
    op0, _ = dop.train(shape, "sarap", "tps", m=200, seed=seed, progress=False)
    op0.compress()
    idx, Q = sample_joint(shape, pr, 1, np.random.default_rng(10_000 + seed), N_Q)
    Qn = Q + (op0.P - mesh.V[pr.handles_at(idx[0])[shape.moving]])
    print(f"\n== frames, {name} ({mesh.n_vertices} vertices), joint compressed with tol {JOINT_TOL:g}:")
    out = {}
    for m in ms:
        try:
            opj, _ = train_movable(shape, pr, "sarap", m=m, seed=seed, progress=False, centres=CENTRES)
        except Exception as exc:  # a solver failure in one training (printed, counted as a miss): the table goes on
            print(f"  m={m}: the joint training failed: {type(exc).__name__}: {exc}")
            out[m] = float("inf")
            continue
        opj.compress(tol=JOINT_TOL)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
            out[m] = frame_row(f"m={m}", op0, opj, Qn, Q, idx[0], mesh.V)
    return out


def run(name, movable, n_place, m_joint, seed=0, n_q=1):
    shape, pr = case(name, movable)
    mesh = shape.mesh
    sizes = [len(v) for v in pr.vertices]
    frac = RADIUS_3D if mesh.dim == 3 else RADIUS
    print(
        f"\n== {name}: {mesh.n_vertices} vertices{' (REDUCED mesh)' if name in SIZES else ''}, {pr.n_movable} "
        f"movable of {shape.n_moving} moving handles (patches of {[len(k) for k in pr.members]}), regions of radius "
        f"{frac:.0%} of the diagonal with {sizes} vertices; load average {os.getloadavg()[0]:.1f}"
    )
    assert min(sizes) >= 20 or name in SIZES, sizes  # a reduced mesh has fewer region vertices
    c0 = time.process_time()
    op0, _ = dop.train(shape, "sarap", "tps", m=200, seed=seed, cache=False, progress=False)
    t_fixed = time.process_time() - c0
    c0 = time.process_time()
    opj, rec = train_movable(
        shape, pr, "sarap", m=m_joint, seed=seed, n_q=n_q, cache=False, progress=False, centres=CENTRES
    )
    t_joint = time.process_time() - c0
    print(
        f"budget: fixed-P training m=200 {t_fixed:.1f} CPU s; joint m={m_joint} ({n_q} Q per placement) "
        f"{t_joint:.1f} CPU s "
        f"(|Ψ| = {opj.basis.size}); ratio {t_joint / t_fixed:.2f}x (target <= 5x); "
        f"converged {int(rec.converged.sum())}/{len(rec.converged)}"
    )
    carry = CarryOp(op0, pr)
    idx, Q = sample_joint(shape, pr, n_place, np.random.default_rng(10_000 + seed), N_Q)
    X, conv = solve_joint(shape, pr, idx, Q, progress=False)
    rows = {k: [] for k in ("joint", "carry", "retrained", *PEERS)}
    fl = {k: [] for k in ("joint", "carry", "retrained")}
    res, bih_seconds = [], []
    for p in range(n_place):
        sl = slice(p * N_Q, (p + 1) * N_Q)
        P, Qp, Xp = idx[sl][0], Q[sl], X[sl]
        sp = shape_at(shape, pr, P)
        opr, _ = dop.train(sp, "sarap", "tps", m=200, seed=seed, progress=False)
        got = {"joint": opj(Qp, P=P), "carry": carry(Qp, P=P), "retrained": opr(Qp)}
        for kind in PEERS:
            peer = peers.make_peer(sp, kind)
            if kind == "biharmonic":
                bih_seconds.append(peer.precompute_time)
            got[kind] = peer(Qp)
        for k, v in got.items():
            rows[k].append(err8a(mesh, v, Xp))
        for k in fl:
            fl[k].append(flips(mesh, got[k]))
        res += [residual(opj, q, P) for q in Qp]
    err = {k: float(np.mean(v)) for k, v in rows.items()}
    print(
        f"held out: {n_place} placements x {N_Q} Q{'' if n_place >= FULL else f' (REDUCED run: {FULL} asked)'}, "
        f"truth converged {int(conv.sum())}/{len(conv)}; mean (8a)/n per frame:"
    )
    for k, v in err.items():
        print(f"  {k:16s} {v:.3e}   joint / this {err['joint'] / v:6.2f}")
    print(
        f"joint / retrained {err['joint'] / err['retrained']:.2f}x (target <= 2x); below MLS rigid, MLS similarity, "
        f"biharmonic: {all(err['joint'] < err[k] for k in PEERS)}; carry / retrained "
        f"{err['carry'] / err['retrained']:.2f}x"
    )
    print(f"biharmonic coordinates re-solve per placement: {np.mean(bih_seconds) * 1e3:.0f} ms (wall, mean)")
    print(f"residual before the correction: max {max(res):.2e}, median {np.median(res):.2e} of the diagonal")
    print("flipped triangles per frame: " + ", ".join(f"{k} {np.mean(v):.2f}" for k, v in fl.items()))
    op0.compress()
    opj.compress(tol=JOINT_TOL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        Qn = Q[:N_Q] + (op0.P - mesh.V[pr.handles_at(idx[0])[shape.moving]])
        print("compressed frame:")
        frame = frame_row(f"m={m_joint}", op0, opj, Qn, Q[:N_Q], idx[0], mesh.V)
        err_c = np.mean(
            [
                err8a(mesh, opj(Q[p * N_Q : (p + 1) * N_Q], P=idx[p * N_Q]), X[p * N_Q : (p + 1) * N_Q])
                for p in range(n_place)
            ]
        )
    print(
        f"joint compressed (tol {JOINT_TOL:g}) error {err_c:.3e}, {err_c / err['retrained']:.2f}x the retrained "
        "(uncompressed)"
    )
    if not SKIP_TABLE:
        frame_table(name, movable, seed=seed)
    return {
        "budget": t_joint / t_fixed,
        "err": err["joint"] / err["retrained"],
        "frame": frame,
        "peers": all(err["joint"] < err[k] for k in PEERS),
    }


#: movable handles, default joint m; Q per placement (fewer rest centres: a cheaper frame)
CASES = {"aleph": (None, 1500), "octopus": ([0, 3, 6], 800), "bar": (None, 1000)}
#: ``--dim 3``: bar_3d's moving end face (one patch of 4 handles, moved by handle 4), two arm tips of the tet octopus;
#: bar_3d's m by the budget rule (at 936 vertices a joint sample cost 1.8x a fixed-P one: m = 900 was 7.9x one
#: fixed-P training at m = 200, so 540 is the largest m near 5x; the tet octopus at 988 vertices: m = 540 was 3.0x)
CASES.update({"bar_3d": (None, 540), "octopus_3d": ([0, 3], 800)})
#: region radius, share of the bounding-box diagonal (2D; 3D: bar_3d's lattice of 1/30 needs 8% for >= 20 vertices)
RADIUS, RADIUS_3D = 0.05, 0.08
#: mesh sizes of the 3D shapes (``BENCH_MOVABLE_VERTICES`` reduces both; the default is the catalogue's)
SIZES = (
    {k: int(os.environ["BENCH_MOVABLE_VERTICES"]) for k in ("bar_3d", "octopus_3d")}
    if os.environ.get("BENCH_MOVABLE_VERTICES")
    else {}
)
#: ``BENCH_MOVABLE_NO_TABLE=1``: skip the frame table at m = 200 and 1,000 (its two joint trainings)
SKIP_TABLE = os.environ.get("BENCH_MOVABLE_NO_TABLE") == "1"
N_Q_TRAIN = int(os.environ.get("BENCH_MOVABLE_NQ", "1"))
#: the joint operator's compression tolerance (the fixed-P one keeps the default, 5e-3)
JOINT_TOL = float(os.environ.get("BENCH_MOVABLE_TOL", "5e-3"))
#: the joint operator's TPS centres (fit_movable(centres=)), default all
CENTRES = int(os.environ["BENCH_MOVABLE_CENTRES"]) if os.environ.get("BENCH_MOVABLE_CENTRES") else None


def main(names=("aleph", "octopus"), n_place=FULL, m_joint=None):
    warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
    t0 = time.perf_counter()
    out = [run(name, CASES[name][0], n_place, m_joint or CASES[name][1], n_q=N_Q_TRAIN) for name in names]
    print(
        f"\ntotal {time.perf_counter() - t0:.0f} s wall; load average {os.getloadavg()[0]:.1f}; "
        f"DEFOP_N_JOBS={os.environ.get('DEFOP_N_JOBS')}"
    )
    return all(r["budget"] <= 5 and r["err"] <= 2 and r["frame"] <= 3 and r["peers"] for r in out)


if __name__ == "__main__":
    args = sys.argv[1:]
    dim = 2
    if "--dim" in args:
        i = args.index("--dim")
        dim = int(args[i + 1])
        del args[i : i + 2]
    names = [a for a in args if a in CASES] or (["bar_3d", "octopus_3d"] if dim == 3 else ["aleph", "octopus"])
    if "frames" in args:
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        ratios = [frame_table(name, CASES[name][0]) for name in names]
        print(f"\nload average {os.getloadavg()[0]:.1f}; DEFOP_N_JOBS={os.environ.get('DEFOP_N_JOBS')}")
        sys.exit(0 if all(r <= 3 for t in ratios for r in t.values()) else 1)
    nums = [int(a) for a in args if a not in CASES]
    sys.exit(0 if main(names, *nums) else 1)
