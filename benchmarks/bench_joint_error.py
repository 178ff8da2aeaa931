"""What limits the joint operator's held-out error (issue 44): per placement and per frame, and the sample designs.

``python benchmarks/bench_joint_error.py <shape> <m> [design ...] [seed=S] [places=N]`` (shape of
``bench_movable.CASES``; designs ``uniform``, ``spread`` (:func:`defop.training.movable.spread_joint`) and
``strat`` (each region vertex equally often, in a seeded order, Q uniform), default ``uniform spread``). On
bench_movable's held-out set (N placements, default 10, × 10 Q; truth and the operators retrained at m = 200 through
``DEFOP_CACHE``), per design: the joint operator's mean (8a)/n over the retrained's, without the worst frame, the
median frame, by placement; with ``uniform`` also per placement the training samples there and a fixed-P TPS fitted
to those samples only (the "samples per placement" floor, where a placement has at least 6), and the worst frames
with their displacement Q − P. Every training's solves go through the cache; the ratios are of errors, no time is
judged.
"""

from __future__ import annotations

import os
import sys
import warnings

import numpy as np

os.environ.setdefault("DEFOP_N_JOBS", "1")
sys.path.insert(0, os.path.dirname(__file__))

import bench_movable as bm  # noqa: E402

import defop as dop  # noqa: E402
from defop.operator.fit import fit_shape  # noqa: E402
from defop.operator.movable import fit_movable  # noqa: E402
from defop.training.movable import sample_joint, shape_at, solve_joint, spread_joint  # noqa: E402
from defop.training.sampling import sample_shape  # noqa: E402

N = bm.N_Q


def stratified(shape, pr, m, rng):
    """m joint samples, each region vertex equally often (±1) in a seeded order, Q uniform at each."""
    cols = []
    for v in pr.vertices:
        reps = np.concatenate([rng.permutation(v) for _ in range(-(-m // len(v)))])[:m]
        cols.append(rng.permutation(reps))
    idx = np.stack(cols, axis=1).astype(np.int64)
    return idx, np.stack([sample_shape(shape_at(shape, pr, i), 1, rng)[0] for i in idx])


def draw(design, shape, pr, m, seed):
    rng = np.random.default_rng(seed)
    if design == "uniform":
        return sample_joint(shape, pr, m, rng)
    if design == "spread":
        return spread_joint(shape, pr, m, rng)
    if design == "strat":
        return stratified(shape, pr, m, rng)
    raise ValueError(f"unknown design {design!r}; known: uniform, spread, strat")


def held_out(shape, pr, n_place):
    """bench_movable's held-out set and the retrained operators' per-frame (8a)/n."""
    idx, Q = sample_joint(shape, pr, n_place, np.random.default_rng(10_000), N)
    X, _ = solve_joint(shape, pr, idx, Q, progress=False)
    ret = []
    for p in range(n_place):
        opr, _ = dop.train(shape_at(shape, pr, idx[p * N]), "sarap", "tps", m=200, seed=0, progress=False)
        ret += [bm.err8a(shape.mesh, opr(Q[i : i + 1]), X[i : i + 1]) for i in range(p * N, (p + 1) * N)]
    return idx, Q, X, np.array(ret)


def per_placement(shape, pr, idx, Q, X, ret, tidx, tQ, tX, fr):
    """Per held-out placement: samples there, joint and retrained error, a fixed-P TPS on those samples only."""
    mesh, floor = shape.mesh, []
    for p in range(len(idx) // N):
        sl = slice(p * N, (p + 1) * N)
        P, at = idx[sl][0], np.all(tidx == idx[p * N], axis=1)
        only = float("nan")
        if at.sum() >= 6:
            only = bm.err8a(mesh, fit_shape(shape_at(shape, pr, P), tQ[at], tX[at], "tps")(Q[sl]), X[sl])
        floor.append(only)
        off = np.linalg.norm(mesh.V[P] - mesh.V[pr.nominal], axis=-1)
        print(
            f"  P {P.tolist()} |P - P0| {np.round(off, 3).tolist()}: {int(at.sum())} samples there; joint "
            f"{fr[sl].mean():.2e}, retrained {ret[sl].mean():.2e} ({fr[sl].mean() / ret[sl].mean():.1f}x); a TPS on "
            f"those samples only {only:.2e}"
        )
    if np.isfinite(floor).any():
        print(f"  samples-per-placement floor: {np.nanmean(floor) / ret.mean():.2f}x the retrained")


def worst_frames(shape, pr, idx, Q, fr, ret, k=6):
    hm = np.array([pr.handles_at(i)[shape.moving] for i in idx])
    off = Q - shape.mesh.V[hm]
    order = np.argsort(fr)[::-1]
    print(
        f"  the worst {k} frames carry {fr[order[:k]].sum() / fr.sum():.0%} of the mean; top frame {fr[order[0]]:.1e}"
    )
    for i in order[:k]:
        print(f"    frame {i}: Q - P {np.round(off[i], 4).tolist()}, joint {fr[i]:.1e}, retrained {ret[i]:.1e}")


def main(name, m, designs, seed=0, n_place=bm.FULL):
    warnings.simplefilter("ignore")
    shape, pr = bm.case(name, bm.CASES[name][0])
    mesh = shape.mesh
    idx, Q, X, ret = held_out(shape, pr, n_place)
    print(
        f"== {name}, joint m = {m}, seed {seed}, {n_place} placements x {N} Q; retrained (8a)/n {ret.mean():.3e} "
        f"(median frame {np.median(ret):.2e}); load average {os.getloadavg()[0]:.1f}"
    )
    for design in designs:
        tidx, tQ = draw(design, shape, pr, m, seed)
        tX, conv = solve_joint(shape, pr, tidx, tQ, progress=False)
        op = fit_movable(mesh, shape.handles, shape.moving, pr, tidx, tQ, tX, {"shape": name})
        fr = np.array([bm.err8a(mesh, op(Q[i : i + 1], P=idx[i]), X[i : i + 1]) for i in range(len(Q))])
        per = fr.reshape(-1, N).mean(axis=1) / ret.mean()
        print(
            f"{design}: joint {fr.mean():.3e} = {fr.mean() / ret.mean():.2f}x the retrained; without the worst "
            f"frame {np.sort(fr)[:-1].mean() / ret.mean():.2f}x; median frame {np.median(fr):.2e}; by placement "
            f"{' '.join(f'{e:.1f}' for e in per)}; converged {int(conv.sum())}/{len(conv)}; load average "
            f"{os.getloadavg()[0]:.1f}",
            flush=True,
        )
        if design == "uniform":
            per_placement(shape, pr, idx, Q, X, ret, tidx, tQ, tX, fr)
            worst_frames(shape, pr, idx, Q, fr, ret)


if __name__ == "__main__":
    args = sys.argv[1:]
    opts = dict(a.split("=") for a in args if "=" in a)
    rest = [a for a in args if "=" not in a]
    main(
        rest[0],
        int(rest[1]),
        rest[2:] or ["uniform", "spread"],
        int(opts.get("seed", 0)),
        int(opts.get("places", bm.FULL)),
    )
