"""The frames of every evaluation path of the fixture operators at fixed random Q: ``frames_f3915d6.npz`` holds
them as the code of f3915d6 (before the one operator core) computed them, and ``tests/test_file_kinds.py`` checks
that this tree computes the same (float64 paths bit for bit; the compiled float32 paths too on the machine that
made them, within float32 round-off elsewhere: fused multiply-adds may differ between CPUs).

Made with the tree of f3915d6 (``git archive f3915d6 defop | tar -x -C OLD``):

    PYTHONPATH=OLD python tests/data/files/frames.py tests/data/files/frames_f3915d6.npz
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
#: the float64 paths (no float32 product, no compiled kernel): equal bit for bit on every machine
EXACT = ("defop_call", "defop_one", "movable_call", "branched-1", "branched-2", "branched-1_E", "branched-2_E")


def frames(folder=HERE, k=8, seed=5):
    """{path name: frames} of the fixture operators in ``folder`` at k random Q per operator."""
    import defop
    from defop.operator.branched import BranchedOperator
    from defop.operator.movable import MovableOp

    rng, out = np.random.default_rng(seed), {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = defop.DefOp.load(folder / "operator-3_tps_rank3.npz")
        Q = op.P + rng.normal(0, 0.3, (k, *op.P.shape))
        Q[0], Q[1] = op.P, op.P + 50.0  # the rest pose, and a row the float32 rule scales
        out["defop_compressed_call"] = op(Q)
        out["defop_compressed_batch"] = op.evaluate_batch(Q)
        out["defop_compressed_fast"] = np.stack([op.evaluate_fast(q) for q in Q])
        op.decompress()
        out["defop_call"], out["defop_one"] = op(Q), np.stack([op(q) for q in Q])
        out["defop_batch"], out["defop_fast"] = op.evaluate_batch(Q), np.stack([op.evaluate_fast(q) for q in Q])
        out["defop_A"], out["defop_B"] = op.compress(tol=1e-3).factors
        m = MovableOp.load(folder / "movable-1.npz")
        P = m.at()["P"]
        Qm = P + rng.normal(0, 0.3, (k, *P.shape))
        Qm[0] = P
        out["movable_compressed_call"], out["movable_compressed_batch"] = m(Qm), m.evaluate_batch(Qm)
        out["movable_compressed_fast"] = np.stack([m.evaluate_fast(q) for q in Qm])
        m.decompress()
        out["movable_call"], out["movable_batch"] = m(Qm), m.evaluate_batch(Qm)
        out["movable_A"], out["movable_B"] = m.compress(rank=2).factors
        for name in ("branched-1", "branched-2"):
            b = BranchedOperator.load(folder / f"{name}.npz")
            Qb = b.P + rng.normal(0, 0.3, (k, *b.P.shape))
            out[name], out[f"{name}_E"] = b(Qb), np.concatenate(b.estimates(Qb), axis=-1)
            out[f"{name}_follow"] = b.session().run(Qb)[1]
    return out


if __name__ == "__main__":
    np.savez_compressed(sys.argv[1], **frames())
