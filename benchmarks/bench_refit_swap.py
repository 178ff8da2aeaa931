"""Do the multilevel policy's lower minima explain its held-out error? Refit with the full policy's minima there.

Trains the aleph (S-ARAP, TPS, m = 200, seed 0, one job) with ``policy="full"`` and ``policy="multilevel"``, lists the
training samples whose energies differ by more than 1e-6 relative (against max(E_full, 1e-3 × median)), then refits
the multilevel operator (``defop.operator.fit.fit``, no new solve) with those samples' X replaced by the full
policy's, and prints the held-out (8a)/n ratio multilevel / full before and after the swap, on the held-out sets of
seeds 12345 and 5000 (``dop.training.held_out``, rest-pose truth). Also the largest difference of the other samples'
X between the two policies, in bounding-box diagonals. ``--truths`` adds the npz files of ``bench_training.py``'s
``--truth-dir`` (Q, the rest-pose and the reference truth, and where they agree): the same ratios against each.

Run: ``DEFOP_CACHE=$(mktemp -d) python benchmarks/bench_refit_swap.py [--shape aleph] [--m 200] [--held-out 100]``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import defop as dop
from defop.analysis.metrics import approximation_error
from defop.operator.fit import fit


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", default="aleph")
    ap.add_argument("--m", type=int, default=200)
    ap.add_argument("--held-out", type=int, default=100)
    ap.add_argument("--truths", nargs="*", default=[], help="npz files of bench_training.py's --truth-dir")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    shape = dop.shapes.load(args.shape)
    trained = {}
    for policy in ("full", "multilevel"):
        t0 = time.process_time()
        trained[policy] = dop.train(shape, "sarap", "tps", m=args.m, seed=0, n_jobs=1, progress=False, policy=policy)
        print(f"{policy}: trained in {time.process_time() - t0:.1f} CPU s", flush=True)
    (full, rf), (multi, rm) = trained["full"], trained["multilevel"]
    solver = dop.variational.Solver(shape.mesh, shape.handles, "sarap")
    Ef, Em = (np.array([solver.energy_of(X) for X in r.X]) for r in (rf, rm))
    scale = np.maximum(Ef, 1e-3 * np.median(Ef))
    moved = np.flatnonzero(np.abs(Em - Ef) > 1e-6 * scale)
    for k in moved:
        print(f"sample {k}: E full {Ef[k]:.9g}, multilevel {Em[k]:.9g} ({(Em[k] - Ef[k]) / scale[k]:+.2e})")
    rest = np.setdiff1d(np.arange(len(Ef)), moved)
    gap = np.abs(rm.X[rest] - rf.X[rest]).max() / shape.mesh.bbox_diagonal
    print(f"the other {len(rest)} samples: X within {gap:.1e} of the diagonal")
    X = rm.X.copy()
    X[moved] = rf.X[moved]
    swapped = fit(shape.mesh, shape.handles, shape.moving, rm.samples, X, "tps", "hat", meta=dict(multi.meta))
    for seed in (12345, 5000):
        Q, Xh, _ = dop.training.held_out(shape, "sarap", args.held_out, seed, n_jobs=1, progress=False)
        e = [float(approximation_error(op, Q, Xh)) for op in (full, multi, swapped)]
        print(
            f"held-out seed {seed} ({args.held_out} Q): (8a)/n full {e[0]:.4e}, multilevel {e[1]:.4e}, swapped "
            f"{e[2]:.4e}; ratio before {e[1] / e[0]:.4f}, after the swap {e[2] / e[0]:.4f}",
            flush=True,
        )
    for path in args.truths:
        t = np.load(path)
        cases = {"rest": (t["Q"], t["X_rest"]), "reference": (t["Q"], t["X"])}
        cases["agree"] = (t["Q"][t["agree"]], t["X"][t["agree"]])
        for name, (Q, Xh) in cases.items():
            e = [float(approximation_error(op, Q, Xh)) for op in (full, multi, swapped)]
            print(
                f"{path.split('/')[-1]} against the {name} truth ({len(Q)} Q): ratio before {e[1] / e[0]:.4f}, "
                f"after the swap {e[2] / e[0]:.4f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
