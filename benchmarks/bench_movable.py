"""Handles that move at rest (issue 38): the joint operator D(x; P, Q) vs retraining, MLS and biharmonic coordinates.

Per shape (the aleph, all 5 handles movable; the octopus, 3 of its 9 movable): placement regions of radius 5% of the
bounding-box diagonal; held-out placements drawn uniformly over the region vertices, × ``N_Q`` configurations Q
each (the Q regions travel with P), truth from the verified solver (problem 6, from the rest pose). Printed, each
with its ratio and target:

* budget: the joint m is where the joint training's work first reaches 5x the work of one fixed-P training at
  m = 200 (``dop.train``, no cache; :func:`defop.training.movable_budget.train_within`, one rule for every shape,
  counted in factor nonzeros rather than time, so the same m on every machine); printed: m, the work ratio and
  the CPU s of the joint training (sampling, every solve of the chunks it ran, fit; no cache) over that fixed-P
  training's (target <= 5x), the fixed-P training timed before and after the joint one and their mean taken (the CPU
  seconds of this shared machine drift with its load: both are printed with the load). All are timed after a small
  training on the shape has compiled the kernels;
* error: mean (8a)/n per held-out frame of the joint operator (design A, TPS over (P, Q − P) with the correction),
  of the carried nominal operator (design B, :class:`defop.operator.movable_carry.CarryOp`), of fixed-P operators
  retrained at each held-out placement (m = 200; target: joint <= 2x), and of MLS rigid, MLS similarity and
  biharmonic coordinates at the same (P, Q) (target: joint below each; biharmonic coordinates' per-placement
  precompute is printed);
* the largest handle residual before the correction (share of the diagonal), flipped triangles per frame (joint,
  carry, retrained);
* side by side at joint m = 200 and the shape's joint m (the budget's), one row each (:func:`compare_row`): the
  error over the retrained (uncompressed and compressed), the compressed joint frame (``evaluate_fast``, P as vertex
  indices and as points) over the compressed fixed-P frame, target <= 3x, beside the multiply-add floor
  (:func:`frame_cost`: the ratio of the two frames' multiply-adds, the logarithms of Ψ counted apart) and the load;
* then every target of the shape again, one line each with its ratio, met or MISSED (:func:`print_targets`).

Everything runs in this process (``DEFOP_N_JOBS=1``) so CPU seconds are this process's ``time.process_time()``.
Run: ``python benchmarks/bench_movable.py [--dim 3] [aleph] [octopus] [bar] [bar_3d] [octopus_3d] [n_placements]
[m_joint]`` (default the aleph, the octopus and the bar; ``--dim 3``: bar_3d, its end-face patch movable, and the tet
octopus, two arm tips movable, regions of 8% of the diagonal, ``BENCH_MOVABLE_VERTICES=n``: both meshed at about n
vertices, a reduced run printed as such); 10 placements, joint m by the budget rule (an explicit ``m_joint`` overrides
it); ``python benchmarks/bench_movable.py frames [shapes]``: the frames alone at m = 200 and 1,000
(:func:`frame_table`); ``python benchmarks/bench_movable.py designs [--dim 3] [shapes] [n_placements] [centres:tol
...]``: the joint frame's designs side by side at the budget, every training through the cache (:func:`designs`,
default :data:`DESIGNS`); ``BENCH_MOVABLE_NQ=5``: 5 Q per training placement; ``BENCH_MOVABLE_TOL``: the joint
operator's compression tolerance, default MovableOp.compress's (2e-2; the fixed-P one keeps 5e-3);
``BENCH_MOVABLE_CENTRES``: its TPS centres, default train_movable's (one per sample), ``all`` or a count); fewer
placements is a reduced run, printed as such. Truth, retrained operators and the m = 200 joint operator go through
``DEFOP_CACHE`` (their cost is not part of any ratio); the two timed trainings never use the cache.
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
from defop.operator.movable import fit_movable, residual  # noqa: E402
from defop.operator.movable_carry import CarryOp  # noqa: E402
from defop.rivals import peers  # noqa: E402
from defop.scene.placement import placement_regions  # noqa: E402
from defop.training.movable import (  # noqa: E402
    sample_joint,
    shape_at,
    solve_joint,
    train_movable,
    training_solves,
)
from defop.training.movable_budget import reference, train_within  # noqa: E402

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


#: the frames are timed alternately this many times, the best of each kept
ROUNDS = 3
#: what one logarithm of Ψ costs in float32 multiply-adds of t B (numba, no SVML: 4.3 ns against 0.11 ns here)
LOG_MACS = 40


def frame_parts(op):
    """The multiply-adds of one compiled TPS frame of ``op`` (a compressed DefOp or MovableOp) by part: the squared
    distances to the centres (dn × |centres|), δψ A' and t B (:func:`defop.operator.kernels.tps_frame`)."""
    k = op.fast_state().kernel
    return k.tps[0].size, k.A.size, k.B.size


def frame_cost(op):
    """(multiply-adds, logarithms) of one compiled TPS frame of ``op`` (:func:`frame_parts` summed; one logarithm,
    in 3D a square root, per centre); the handles' correction (a few bumps) is left out."""
    return sum(frame_parts(op)), op.fast_state().kernel.tps[0].shape[1]


def frame_row(label, op0, opj, Qn, Q, P, V, errors=""):
    """Time the compressed fixed-P frame (at Qn) and the joint frame (at Q, P as vertices and as points V[P]),
    alternately :data:`ROUNDS` times, the best of each (the same load), and print the ratios (wall and this
    thread's CPU time, the steadier on a busy machine) beside the multiply-add floor (and ``errors``, the row's error
    ratios). Returns the CPU ratio and the floor (multiply-adds, logarithms apart)."""
    points = V[P]  # the same array each frame, as an editor's drag passes it
    runs = [
        (frame_seconds(op0.evaluate_fast, Qn), frame_seconds(lambda q: opj.evaluate_fast(q, P=P), Q))
        for _ in range(ROUNDS)  # alternating, the best of each: the same load for both
    ]
    (tf, cf), (tj, cj) = (tuple(np.min([r[i] for r in runs], axis=0)) for i in (0, 1))
    tp, cp = frame_seconds(lambda q: opj.evaluate_fast(q, P=points), Q)
    (mf, lf), (mj, lj) = frame_cost(op0), frame_cost(opj)
    parts = " + ".join(f"{a} / {b}" for a, b in zip(frame_parts(opj), frame_parts(op0), strict=True))
    print(
        f"  {label}: fixed-P rank {op0.rank} {tf * 1e6:.1f} µs; joint |Ψ| {opj.basis.size} rank {opj.rank} "
        f"{tj * 1e6:.1f} µs (P as points {tp * 1e6:.1f} µs): ratio {tj / tf:.2f}x wall, {cj / cf:.2f}x CPU, P as "
        f"points {cp / cf:.2f}x CPU "
        f"(target <= 3x); floor {mj / mf:.2f}x multiply-adds ({mj} / {mf}: distances, δψ A, t B {parts}), "
        f"logs {lj} / {lf}, "
        f"{(mj + LOG_MACS * lj) / (mf + LOG_MACS * lf):.2f}x with a log as {LOG_MACS} multiply-adds; "
        f"{errors}load average {os.getloadavg()[0]:.1f}"
    )
    return cj / cf, mj / mf


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
    print(f"\n== frames, {name} ({mesh.n_vertices} vertices), joint compressed with tol {tol_label()}:")
    out = {}
    for m in ms:
        try:
            opj, _ = train_movable(shape, pr, "sarap", m=m, seed=seed, progress=False, **CENTRES)
        except Exception as exc:  # a solver failure in one training (printed, counted as a miss): the table goes on
            print(f"  m={m}: the joint training failed: {type(exc).__name__}: {exc}")
            out[m] = float("inf")
            continue
        compress_joint(opj)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
            out[m] = frame_row(f"m={m}", op0, opj, Qn, Q, idx[0], mesh.V)[0]
    return out


def warm(shape, pr, seed=0):
    """Compile the solver's kernels (numba) before any timed training: a small fixed-P training and two joint solves
    on the shape, no cache."""
    dop.train(shape, "sarap", "tps", m=40, seed=seed + 1, cache=False, progress=False)
    idx, Q = sample_joint(shape, pr, 2, np.random.default_rng(seed + 1))
    solve_joint(shape, pr, idx, Q, progress=False, cache=False)


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
    warm(shape, pr, seed)  # the kernels compiled before either timed training (numba JIT)
    load_fixed, c0 = os.getloadavg()[0], time.process_time()
    op0, rec0 = dop.train(shape, "sarap", "tps", m=200, seed=seed, cache=False, progress=False)
    t_fixed = time.process_time() - c0
    c0 = time.process_time()
    if m_joint:  # an explicit m: train_movable at it
        opj, rec = train_movable(
            shape, pr, "sarap", m=m_joint, seed=seed, n_q=n_q, cache=False, progress=False, **CENTRES
        )
    else:
        opj, rec = train_within(shape, pr, rec0, seed=seed, n_q=n_q, cache=False, progress=False, **CENTRES)
        m_joint = len(rec.idx)
    t_joint = time.process_time() - c0
    load_joint, c0 = os.getloadavg()[0], time.process_time()
    dop.train(shape, "sarap", "tps", m=200, seed=seed, cache=False, progress=False)  # again, after: the load drifts
    t_after = time.process_time() - c0
    t_before, t_fixed = t_fixed, (t_fixed + t_after) / 2
    rule = (
        f"work {(rec.work + rec.budget['fit']) / rec0.work:.2f}x one fixed-P training's (solves + fit; the rule: "
        f"first >= {rec.budget['factor']:g}x; "
        f"{rec.budget['solved']} samples solved to find m)"
        if rec.budget
        else "m given"
    )
    print(
        f"budget: fixed-P training m=200 {training_solves(rec0)} solves, {t_fixed:.1f} CPU s (before the joint "
        f"{t_before:.1f} at load {load_fixed:.1f}, after {t_after:.1f} at load {os.getloadavg()[0]:.1f}), work "
        f"{rec0.work:.3e}; "
        f"joint m={m_joint} ({n_q} Q per placement), {rule}; {t_joint:.1f} CPU s "
        f"(|Ψ| = {opj.basis.size}); CPU ratio {t_joint / t_fixed:.2f}x (target <= 5x); "
        f"converged {int(rec.converged.sum())}/{len(rec.converged)}; load average {load_joint:.1f}"
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
    held = (idx, Q, X, n_place)
    print(f"compressed frame (fixed-P m=200 compressed with tol 5e-3, joint with tol {tol_label()}):")
    frame = {}
    for m in (200, m_joint):
        opm = opj if m == m_joint else train_movable(shape, pr, "sarap", m=m, seed=seed, progress=False, **CENTRES)[0]
        frame[m] = compare_row(f"m={m}", op0, opm, held, err["retrained"], mesh, pr)[0]
    out = {
        "budget": t_joint / t_fixed,
        "err": err["joint"] / err["retrained"],
        "frame": frame[m_joint][0],
        "peers": all(err["joint"] < err[k] for k in PEERS),
    }
    print_targets(name, out, err, frame, n_place)
    return out


def print_targets(name, out, err, frame, n_place):
    """The shape's targets, one line each: its ratio, the target, met or MISSED (``frame``: {m: (CPU ratio, floor)}
    of :func:`compare_row`), and the load average."""

    def verdict(ok):
        return "met" if ok else "MISSED"

    size = "full size" if n_place >= FULL else f"REDUCED run: {n_place} of {FULL} placements"
    print(f"targets, {name} ({n_place} placements x {N_Q} Q, {size}):")
    print(
        f"  budget: joint training CPU {out['budget']:.2f}x one fixed-P training (<= 5x): {verdict(out['budget'] <= 5)}"
    )
    print(f"  error: {out['err']:.2f}x the retrained at m = 200 (<= 2x): {verdict(out['err'] <= 2)}")
    below = ", ".join(f"{k} {err[k] / err['joint']:.1f}x" for k in PEERS)
    print(f"  below the peers (their error over the joint's: {below}): {verdict(out['peers'])}")
    for m, (ratio, floor) in frame.items():
        print(f"  frame at m = {m}: {ratio:.2f}x CPU (<= 3x; floor {floor:.2f}x multiply-adds): {verdict(ratio <= 3)}")
    print(f"  load average {os.getloadavg()[0]:.1f}")


def joint_error(opj, held, mesh):
    """Mean (8a)/n per held-out frame of ``opj`` (every placement's batch at its P)."""
    idx, Q, X, n_place = held
    return float(
        np.mean(
            [
                err8a(mesh, opj(Q[p * N_Q : (p + 1) * N_Q], P=idx[p * N_Q]), X[p * N_Q : (p + 1) * N_Q])
                for p in range(n_place)
            ]
        )
    )


def compare_row(label, op0, opj, held, e_ret, mesh, pr, tol=None):
    """One row of the side-by-side table: the joint operator's error over the retrained (uncompressed and
    compressed, with ``tol`` or ``BENCH_MOVABLE_TOL``), then its compressed frame over the fixed-P one
    (:func:`frame_row`). Returns ((the frame's CPU ratio, its multiply-add floor), the compressed error's ratio)."""
    idx, Q, X, _ = held
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        e_u = joint_error(opj, held, mesh)
        compress_joint(opj, tol)
        e_c = joint_error(opj, held, mesh)
        Qn = Q[:N_Q] + (op0.P - mesh.V[pr.handles_at(idx[0])[op0.moving]])
        errors = f"error {e_u / e_ret:.2f}x retrained, compressed {e_c / e_ret:.2f}x (target <= 2x); "
        return frame_row(label, op0, opj, Qn, Q[:N_Q], idx[0], mesh.V, errors), e_c / e_ret


def retrained(shape, pr, n_place, seed=0):
    """The held-out set (placements × :data:`N_Q` Q, truth through the cache) and the mean (8a)/n of fixed-P
    operators retrained at m = 200 at each of its placements (through the cache): ``(held, error)``."""
    idx, Q = sample_joint(shape, pr, n_place, np.random.default_rng(10_000 + seed), N_Q)
    X, _ = solve_joint(shape, pr, idx, Q, progress=False)
    errors = []
    for p in range(n_place):
        sl = slice(p * N_Q, (p + 1) * N_Q)
        opr, _ = dop.train(shape_at(shape, pr, idx[sl][0]), "sarap", "tps", m=200, seed=seed, progress=False)
        errors.append(err8a(shape.mesh, opr(Q[sl]), X[sl]))
    return (idx, Q, X, n_place), float(np.mean(errors))


#: ``designs``: the joint frame's designs compared at the budget, (TPS centres, compression tolerance) each
DESIGNS = (("auto", 2e-2), (400, 2e-2), (200, 2e-2), ("auto", 5e-2), (200, 5e-2))


def designs(name, movable, n_place, specs=DESIGNS, seed=0):
    """The joint operator at the budget (one training through the cache by the rule of :func:`run`,
    :func:`defop.training.movable_budget.train_within` against the fixed-P training at m = 200, refitted per design by
    :func:`defop.operator.movable.fit_movable`) for each (centres, tol) of ``specs``: its error over the retrained
    and its compressed frame over the fixed-P one beside the floor (:func:`compare_row`), one row each.
    Returns {(centres, tol): ((frame CPU ratio, floor), compressed error ratio)}."""
    shape, pr = case(name, movable)
    mesh = shape.mesh
    op0, rec0 = reference(shape, m=200, seed=seed, progress=False)  # its work, from the cache or trained again
    _, rec = train_within(shape, pr, rec0, seed=seed, progress=False)
    m_joint = len(rec.idx)
    held, e_ret = retrained(shape, pr, n_place, seed)
    op0.compress()
    print(
        f"\n== designs, {name} ({mesh.n_vertices} vertices{', REDUCED mesh' if name in SIZES else ''}), joint "
        f"m = {m_joint} (the budget), {n_place} placements x {N_Q} Q{'' if n_place >= FULL else ' (REDUCED)'}, "
        f"retrained (8a)/n {e_ret:.3e}; fixed-P compressed with tol 5e-3:"
    )
    out = {}
    for centres, tol in specs:
        opj = fit_movable(
            mesh, shape.handles, shape.moving, pr, rec.idx, rec.Q, rec.X, {"shape": name}, centres=centres
        )
        out[(centres, tol)] = compare_row(f"centres {centres}, tol {tol:g}", op0, opj, held, e_ret, mesh, pr, tol)
    return out


def design_spec(text):
    """``centres:tol`` (centres ``auto``, ``all`` or a count) as (centres, tol)."""
    c, tol = text.split(":")
    return ("auto" if c == "auto" else None if c == "all" else int(c)), float(tol)


#: movable handles, joint m (None: train_within against the fixed-P training at m = 200, one rule for every shape)
CASES = {"aleph": (None, None), "octopus": ([0, 3, 6], None), "bar": (None, None)}
#: ``--dim 3``: bar_3d's moving end face (one patch of 4 handles, moved by handle 4), two arm tips of the tet octopus
CASES.update({"bar_3d": (None, None), "octopus_3d": ([0, 3], None)})
#: region radius, share of the bounding-box diagonal (2D; 3D: bar_3d's lattice of 1/30 needs 8% for >= 20 vertices)
RADIUS, RADIUS_3D = 0.05, 0.08
#: mesh sizes of the 3D shapes (``BENCH_MOVABLE_VERTICES`` reduces both; the default is the catalogue's)
SIZES = (
    {k: int(os.environ["BENCH_MOVABLE_VERTICES"]) for k in ("bar_3d", "octopus_3d")}
    if os.environ.get("BENCH_MOVABLE_VERTICES")
    else {}
)
N_Q_TRAIN = int(os.environ.get("BENCH_MOVABLE_NQ", "1"))
#: the joint operator's compression tolerance (default: MovableOp.compress's; the fixed-P one keeps 5e-3)
JOINT_TOL = float(os.environ["BENCH_MOVABLE_TOL"]) if os.environ.get("BENCH_MOVABLE_TOL") else None
#: the joint operator's TPS centres (train_movable(centres=)): default its own (one per sample), "all" or a count
_C = os.environ.get("BENCH_MOVABLE_CENTRES", "")
CENTRES = {} if not _C else {"centres": None if _C == "all" else int(_C)}


def compress_joint(opj, tol=None):
    """Compress the joint operator with ``tol``, else ``BENCH_MOVABLE_TOL`` (default MovableOp.compress's own)."""
    tol = JOINT_TOL if tol is None else tol
    return opj.compress() if tol is None else opj.compress(tol=tol)


def tol_label():
    return f"{JOINT_TOL:g}" if JOINT_TOL is not None else "the default"


def main(names=("aleph", "octopus", "bar"), n_place=FULL, m_joint=None):
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
    names = [a for a in args if a in CASES] or (["bar_3d", "octopus_3d"] if dim == 3 else ["aleph", "octopus", "bar"])
    if "frames" in args:
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        ratios = [frame_table(name, CASES[name][0]) for name in names]
        print(f"\nload average {os.getloadavg()[0]:.1f}; DEFOP_N_JOBS={os.environ.get('DEFOP_N_JOBS')}")
        sys.exit(0 if all(r <= 3 for t in ratios for r in t.values()) else 1)
    if "designs" in args:
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        specs = [design_spec(a) for a in args if ":" in a] or DESIGNS
        n_place = next((int(a) for a in args if a.isdigit()), FULL)
        rows = [designs(name, CASES[name][0], n_place, specs) for name in names]
        print(f"\nload average {os.getloadavg()[0]:.1f}; DEFOP_N_JOBS={os.environ.get('DEFOP_N_JOBS')}")
        sys.exit(0 if all(f[0] <= 3 and e <= 2 for r in rows for f, e in r.values()) else 1)
    nums = [int(a) for a in args if a not in CASES]
    sys.exit(0 if main(names, *nums) else 1)
