"""DefOp: batch evaluation, compression, save/load round trip, bad input and extrapolation warnings."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.operator import DefOp, ExtrapolationWarning


@pytest.fixture(scope="module")
def op_and_data():
    s = dop.shapes.load("bar", n_vertices=250)
    solver = dop.solve.Solver(s.mesh, s.handles, "arap")
    Q = dop.sampling.sample_shape(s, 25, np.random.default_rng(0))
    X = np.array([solver.solve(s.targets(q)).X for q in Q])
    return s, dop.fit.fit_shape(s, Q, X, "tps", meta={"energy": "arap"}), Q, X


def test_single_and_batch_agree(op_and_data):
    s, op, Q, _ = op_and_data
    batch = op(Q[:5])
    assert batch.shape == (5, s.mesh.n_vertices, 2)
    assert np.allclose(batch[2], op(Q[2])) and np.allclose(op.evaluate_fast(Q[2]), op(Q[2]))


def test_compression_is_controlled(op_and_data):
    s, op, Q, X = op_and_data
    exact = op(Q)
    op.compress(tol=1e-6)
    try:
        assert op.rank < op.handle_basis.size
        assert np.abs(op(Q) - exact).max() <= 1e-5 * s.mesh.bbox_diagonal
    finally:
        op.decompress()
    assert np.array_equal(op(Q), exact)


def test_compressed_factors_are_float32_and_results_float64(op_and_data, tmp_path):
    s, op, Q, _ = op_and_data
    exact = op(Q[:3])
    op.compress(tol=1e-6)
    try:
        assert all(f.dtype == np.float32 for f in op.factors)
        fast, batch = op.evaluate_fast(Q[1]), op(Q[:3])
        assert fast.dtype == batch.dtype == np.float64
        assert np.allclose(fast, batch[1], rtol=0, atol=1e-6 * s.mesh.bbox_diagonal)
        assert np.abs(batch - exact).max() <= 1e-5 * s.mesh.bbox_diagonal
        op.save(tmp_path / "c.npz")
        back = DefOp.load(tmp_path / "c.npz")
        assert back.factors[1].dtype == np.float32 and np.array_equal(back(Q[:3]), batch)
    finally:
        op.decompress()


def test_save_load_round_trip(op_and_data, tmp_path):
    s, op, Q, _ = op_and_data
    op.save(tmp_path / "op.npz")
    back = DefOp.load(tmp_path / "op.npz")
    assert np.array_equal(back(Q), op(Q))
    assert back.meta == op.meta and back.meta["shape"] == "bar" and back.meta["energy"] == "arap"
    assert back.meta["basis"] == "tps" and back.meta["n_samples"] == 25 and "version" in back.meta
    back.check_mesh(s.mesh)


def test_corrupt_and_incompatible_files(op_and_data, tmp_path):
    _, op, _, _ = op_and_data
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match="not a readable defop operator file"):
        DefOp.load(junk)
    np.savez(tmp_path / "other.npz", header=np.array('{"format": "something-else"}'))
    with pytest.raises(ValueError, match="has format 'something-else'"):
        DefOp.load(tmp_path / "other.npz")
    with pytest.raises(ValueError, match="no such operator file"):
        DefOp.load(tmp_path / "missing.npz")


def test_bad_Q_and_other_mesh(op_and_data):
    s, op, _, _ = op_and_data
    with pytest.raises(ValueError, match=r"Q must have shape \(1, 2\)"):
        op(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        op(np.array([[np.nan, 0.0]]))
    other = dop.shapes.load("bar", n_vertices=300).mesh
    with pytest.raises(ValueError, match="trained on a mesh with"):
        op.check_mesh(other)


def test_extrapolation_warning(op_and_data):
    s, op, _, _ = op_and_data
    with pytest.warns(ExtrapolationWarning, match="moving handle 0 .* extrapolates"):
        op(s.P_moving + [[3.0, 0.0]])
