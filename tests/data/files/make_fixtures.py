"""Make the operator-side file fixtures of ``tests/data/files/`` (run from the repository root, once).

    python tests/data/files/make_fixtures.py

Every file is small (a 2 x 1 rectangle of about 60 vertices) and synthetic: its operators are fitted (or built)
from smooth made-up displacements, since a loader's answer does not depend on where W came from. The answers
each file gives (``op(Q)`` at a few fixed Q, at load time) are stored in ``expected.npz``; ``tests/test_file_kinds.py``
checks that every file still loads to them, bit for bit, or is refused by name, forever. Do not regenerate the
files when the code changes: they stand for files users have on disk.

How each was made:

* ``operator-3_tps_rank3.npz``, ``operator-3_quadratic.npz``: :meth:`DefOp.save` of this tree (format
  ``defop-operator-3``), a compressed TPS operator and an uncompressed quadratic one.
* ``operator-2_*``: the files of 7c4dc5f in ``tests/data/`` (``op_7c4dc5f_*.npz``, format ``defop-operator-2``) serve.
* ``operator-1_tps.npz``: format ``defop-operator-1`` (before (★)): the format-3 arrays without ``dim`` and
  ``kernel``, the header's format ``defop-operator-1``; its factors are recomputed at load (``meta.rank``).
* ``branched-2.npz``: :meth:`BranchedOperator.save` of this tree (format ``defop-branched-2``): two branches, each
  with its own domain TPS.
* ``branched-1.npz``: format ``defop-branched-1``, as the writer of 0.1 laid it out (λ²_b as ``b<k>.margin``, no
  ``domain_w``/``domain_centers``/``box``, header without ``domain`` entries).
* ``movable-1.npz``: :meth:`MovableOp.save` of this tree (format ``defop-movable-1``), compressed.
* ``cache-entry.npz``: a ground-truth entry of :class:`defop.training.cache.Cache` (``X``, ``converged``,
  ``__meta__``); not an operator file: every operator loader names it as a cache entry.
* ``mesh.npz``: :func:`defop.geometry.mesh.write_mesh`; every operator loader names it as a mesh file.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np

import defop as dop
from defop.geometry.mesh import write_mesh
from defop.operator.branched import Branch, BranchedOperator
from defop.operator.domains import fit_domain
from defop.operator.fit import fit
from defop.operator.movable import fit_movable
from defop.scene.placement import placement_regions
from defop.training.cache import Cache
from defop.training.movable import sample_joint

HERE = Path(__file__).parent


def rectangle():
    outer = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    H = np.array([[1.8, 0.5], [1.0, 0.8], [0.1, 0.5]])
    return dop.shapes.from_polygon(
        outer,
        handles=H,
        moving=[True, True, False],
        n_vertices=60,
        name="rect",
        regions=[{"kind": "disc", "radius": 0.3}] * 2,
    )


def synthetic(shape, Q, amp=0.3):
    """Smooth made-up deformations at Q (m, n, 2): x + amp sin(x · (Q − P)ᵀ)."""
    V, P = shape.mesh.V, shape.mesh.V[shape.handles[shape.moving]]
    return np.stack([V + amp * np.sin(V @ (q - P).T)[:, :2] for q in Q])


def samples(shape, m, seed, r=0.2):
    P = shape.mesh.V[shape.handles[shape.moving]]
    return P + np.random.default_rng(seed).uniform(-r, r, (m, *P.shape))


def main():
    shape = rectangle()
    mesh, handles, moving = shape.mesh, shape.handles, shape.moving
    Q = samples(shape, 6, 99, r=0.15)  # the evaluation points of every expected answer
    expected = {"Q": Q}
    S = samples(shape, 12, 1)

    op = fit(mesh, handles, moving, S, synthetic(shape, S), basis="tps", spatial="hat").compress(rank=3)
    op.save(HERE / "operator-3_tps_rank3.npz")
    expected["operator-3_tps_rank3"] = op(Q)
    S2 = samples(shape, 16, 2)
    opq = fit(mesh, handles, moving, S2, synthetic(shape, S2), basis="quadratic", spatial="hat")
    opq.save(HERE / "operator-3_quadratic.npz")
    expected["operator-3_quadratic"] = opq(Q)

    # format 1: the format-3 arrays under a format-1 header (no dim, no kernel); factors recomputed at load
    with np.load(HERE / "operator-3_tps_rank3.npz") as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["header"]))
    header = {
        "format": "defop-operator-1",
        "format_version": 1,
        "meta": header["meta"],
        "basis": {k: v for k, v in header["basis"].items() if k != "kernel"},
    }
    arrays["header"] = np.array(json.dumps(header))
    with open(HERE / "operator-1_tps.npz", "wb") as fh:
        np.savez(fh, **arrays)
    expected["operator-1_tps"] = dop.DefOp.load(HERE / "operator-1_tps.npz")(Q)

    # branched: two branches (the second bent the other way), domains fitted from both sides
    ops, branches = [], []
    for b, amp in enumerate((0.3, -0.3)):
        Sb = samples(shape, 10, 10 + b)
        opb = fit(mesh, handles, moving, Sb, synthetic(shape, Sb, amp), basis="tps", spatial="hat")
        energy = np.zeros(opb.handle_basis.size)
        energy[0] = 1.0 + b
        values = np.where(np.arange(len(Sb)) % 3 == 0, -0.1, 0.1)
        dom = fit_domain(opb.P, opb.handle_basis.scale, Sb, values)
        margin = np.zeros(opb.handle_basis.size)
        margin[0] = 1.0
        ops.append(opb)
        branches.append(Branch(b, opb, energy, margin, 1 if b == 0 else -1, domain=dom))
    mode = np.zeros_like(mesh.V)
    mode[:, 1] = 1.0 / np.sqrt(mesh.mass_matrix.diagonal().sum())
    threshold = np.zeros(1 + ops[0].P.size)
    bop = BranchedOperator(branches, mode, threshold, {"shape": "rect"})
    bop.save(HERE / "branched-2.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected["branched-2"] = bop(Q)
        expected["branched-2_labels"] = bop.choose(Q)

    # branched version 1: the version-2 archive without the domains and the box, λ² (margin) as the domain
    with np.load(HERE / "branched-2.npz") as z:
        arrays = {k: z[k] for k in z.files if not k.endswith(("domain_w", "domain_centers")) and k != "box"}
    header = json.loads(str(arrays["header"]))
    header.update(format="defop-branched-1", format_version=1)
    for e in header["branches"]:
        e.pop("domain")
    arrays["header"] = np.array(json.dumps(header))
    with open(HERE / "branched-1.npz", "wb") as fh:
        np.savez(fh, **arrays)
    v1 = BranchedOperator.load(HERE / "branched-1.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected["branched-1"] = v1(Q)
        expected["branched-1_labels"] = v1.choose(Q)

    # movable handles
    placement = placement_regions(shape, [0, 1], radius=0.3)
    idx, QJ = sample_joint(shape, placement, 12, 3)
    P0 = mesh.V[placement.handles_at(idx[0])[moving]]
    X = np.stack([mesh.V + 0.3 * np.sin(mesh.V @ (q - P0).T)[:, :2] for q in QJ])
    mop = fit_movable(mesh, handles, moving, placement, idx, QJ, X).compress(rank=3)
    mop.save(HERE / "movable-1.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected["movable-1"] = mop(Q)
        expected["movable-1_fast"] = np.stack([mop.evaluate_fast(q) for q in Q])

    # not operator files
    (HERE / "_cache").mkdir(exist_ok=True)
    cache = Cache(HERE / "_cache")
    path = cache.store("gt", "fixture", {"X": X[:2], "converged": np.ones(2, bool)}, meta={"times": [0.1, 0.2]})
    shutil.move(path, HERE / "cache-entry.npz")
    shutil.rmtree(HERE / "_cache")
    write_mesh(HERE / "mesh.npz", mesh)

    with open(HERE / "expected.npz", "wb") as fh:
        np.savez(fh, **expected)
    print(sorted(p.name for p in HERE.glob("*.npz")))


if __name__ == "__main__":
    main()
