"""The whole pipeline in 3D on a small tetrahedral bar: sample Q_k in balls, solve D^E (verified), fit Ψ on R^{3H},
and the guarantees on every evaluation path: Prop. 2 (handles exact), (8b) (rest pose exact), Prop. 1 (TPS
reproduces every training deformation), save/load and compression, as in 2D."""

from __future__ import annotations

import numpy as np
import pytest
from reference3d import box_tets  # tests/ is on sys.path (rootdir conftest)

import defop as dop


@pytest.fixture(scope="module")
def bar3():
    V, T = box_tets((6, 1, 1), (1.0, 0.2, 0.2))
    mesh = dop.Mesh(V, T)
    left = np.flatnonzero(V[:, 0] == 0.0)  # the 4 corners of the clamped end
    right = np.flatnonzero(V[:, 0] == 1.0)  # the 4 corners of the dragged end, in a shuffled order
    right = np.random.default_rng(1).permutation(right)
    handles = np.concatenate([right, left])
    moving = np.arange(len(handles)) < len(right)
    regions = [{"kind": "ball", "radius": 0.08}] * len(right)
    return dop.Shape(name="bar3", mesh=mesh, handles=handles, moving=moving, regions=regions)


@pytest.fixture(scope="module")
def trained(bar3):
    m = dop.training.min_samples("tps", bar3.n_moving, d=3) + 4
    return dop.train(bar3, energy="sarap", basis="tps", m=m, seed=0, cache=False, n_jobs=1, progress=False)


def test_training_in_3d_solves_verified_minima(trained):
    op, record = trained
    assert op.d == 3 and op.mesh.dim == 3
    assert np.asarray(record.converged).all()


def test_props_1_and_2_and_8b_hold_on_every_path_in_3d(bar3, trained, tmp_path):
    op, record = trained
    rng = np.random.default_rng(7)
    Q = bar3.P_moving + rng.uniform(-0.06, 0.06, size=(5,) + bar3.P_moving.shape)
    moving = bar3.handles[bar3.moving]
    op.save(tmp_path / "bar3.npz")
    loaded = dop.DefOp.load(tmp_path / "bar3.npz")
    compressed = dop.DefOp.load(tmp_path / "bar3.npz").compress()  # compress() works in place
    for path in (op, loaded, compressed):
        batch = path(Q)
        assert batch.shape == (5, bar3.mesh.n_vertices, 3)
        assert np.abs(batch[:, moving] - Q).max() <= 1e-12  # Prop. 2
        assert np.abs(path.evaluate_fast(Q[0])[moving] - Q[0]).max() <= 1e-12
        assert np.abs(path(bar3.P_moving) - bar3.mesh.V).max() == 0.0  # (8b), to the last bit
    # Prop. 1: the TPS operator reproduces its training deformations X_k = D^E(·, Q_k), on the exact paths
    assert record.X is not None and len(record.X) == len(record.samples)
    for path in (op, loaded):
        assert np.abs(path(record.samples) - record.X).max() <= 1e-9 * bar3.mesh.bbox_diagonal


def test_a_2d_q_on_a_3d_operator_is_named(bar3, trained):
    op, _ = trained
    with pytest.raises(ValueError, match="Q"):
        op(bar3.P_moving[:, :2])
