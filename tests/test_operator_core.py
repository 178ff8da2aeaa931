"""The one operator core (defop.operator.core): every kind refuses a non-finite Ψ and non-integer vertex indices
through the shared code, returns (0, n_vertices, d) for an empty batch, and keeps its guarantees on every path."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from defop.operator import core
from defop.operator.branched import BranchedOperator
from defop.operator.defop import DefOp
from defop.operator.movable import MovableOp

FILES = Path(__file__).parent / "data" / "files"


@pytest.fixture(scope="module")
def ops():
    """One operator of each kind (the file fixtures), compressed and not: {name: (op, P)}."""
    out = {}
    for tag, path in (("defop", "operator-3_tps_rank3.npz"), ("quadratic", "operator-3_quadratic.npz")):
        op = DefOp.load(FILES / path)
        out[tag] = (op, op.P)
    out["defop-exact"] = (DefOp.load(FILES / "operator-3_tps_rank3.npz").decompress(), out["defop"][1])
    bop = BranchedOperator.load(FILES / "branched-2.npz")
    out["branched"] = (bop, bop.P)
    for tag, compressed in (("movable", True), ("movable-exact", False)):
        mop = MovableOp.load(FILES / "movable-1.npz")
        if not compressed:
            mop.decompress()
        out[tag] = (mop, mop.at()["P"])
    return out


KINDS = ["defop", "quadratic", "defop-exact", "branched", "movable", "movable-exact"]


def _paths(op):
    """The evaluation paths of one frame Q of ``op``."""
    paths = {"call": op}
    if hasattr(op, "evaluate_fast"):
        paths["fast"] = op.evaluate_fast
        paths["batch"] = lambda Q: op.evaluate_batch(Q[None])
    return paths


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("offset", [1e160, 1e200, 1e300])
def test_a_far_q_is_refused_on_every_path(ops, kind, offset):
    """Before: MovableOp returned a frame full of NaN (with only an extrapolation warning) where DefOp and
    BranchedOperator refuse a non-finite Ψ."""
    op, P = ops[kind]
    Q = P.copy()
    Q[0, 0] += offset
    for name, f in _paths(op).items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", core.ExtrapolationWarning)
            with pytest.raises(ValueError, match=r"not finite at Q") as info:
                f(Q)
        assert "Q" in str(info.value), name


@pytest.mark.parametrize("kind", KINDS)
def test_an_empty_batch_gives_zero_frames(ops, kind):
    """Before: MovableOp raised numpy's 'zero-size array to reduction operation maximum'."""
    op, P = ops[kind]
    n_vertices, d = op.mesh.n_vertices, op.mesh.V.shape[1]
    empty = np.zeros((0, *P.shape))
    assert op(empty).shape == (0, n_vertices, d)
    if hasattr(op, "evaluate_batch"):
        assert op.evaluate_batch(empty).shape == (0, n_vertices, d)


@pytest.mark.parametrize("bad", [[0.5, 1.0, 2.0], [np.nan, 1, 2], [True, False, True], [[0, 1, 2]]])
def test_non_integer_handles_are_refused_by_every_kind(ops, bad):
    """Before: DefOp and MovableOp truncated fractional vertex indices (np.asarray(handles, int64))."""
    op = ops["defop-exact"][0]
    with pytest.raises(ValueError, match=r"handles must be a 1-D array of integer vertex indices"):
        DefOp(op.mesh, bad, op.moving, op.handle_basis, op.W)
    mop = ops["movable-exact"][0]
    with pytest.raises(ValueError, match=r"handles must be a 1-D array of integer vertex indices"):
        MovableOp(mop.mesh, bad, mop.moving, mop.placement, mop.basis, mop.W, mop.scales)


def test_out_of_range_handles_are_refused(ops):
    op = ops["defop-exact"][0]
    with pytest.raises(ValueError, match=rf"handles must be vertex indices in \[0, {op.n_vertices}\)"):
        DefOp(op.mesh, [0, 1, op.n_vertices], op.moving, op.handle_basis, op.W)


def test_integral_float_handles_are_the_same_operator(ops):
    op = ops["defop-exact"][0]
    same = DefOp(op.mesh, op.handles.astype(float), op.moving, op.handle_basis, op.W)
    assert same.handles.dtype == np.int64 and np.array_equal(same(op.P + 0.01), op(op.P + 0.01))


def test_one_extrapolation_judgement():
    reach = np.array([1.0, 2.0])
    far = core.beyond_reach(np.array([1.5, 3.0 + 1e-9]), reach)
    assert far.tolist() == [False, True]
    assert core.EXTRAPOLATION_FACTOR == 1.5


def test_the_float32_rule_scales_only_rows_beyond_its_bound():
    M = (np.arange(12, dtype=np.float32).reshape(3, 4) - 5.0) * 1e-3
    dpsi = np.array([[1.0, 2.0, -3.0], [1e35, 0.0, 2e35]])
    y = core.reduced_product(dpsi, (M,))
    assert np.array_equal(y[0], (dpsi[0].astype(np.float32) @ M).astype(float))
    assert np.isfinite(y).all() and np.allclose(y[1], dpsi[1] @ M.astype(float), rtol=1e-6)


def _q(P, xy):
    return P + np.asarray(xy).reshape(P.shape) * 0.2


@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_guarantees_on_every_path_at_random_q(ops, data):
    """Prop. 2 (the moving handles on Q, exactly) and (8b) (the rest pose is x, bit for bit) on every path of every
    kind, at random valid Q."""
    kind = data.draw(st.sampled_from(["defop", "quadratic", "defop-exact", "movable", "movable-exact"]))
    op, P = ops[kind]
    xy = data.draw(st.lists(st.floats(-1, 1), min_size=P.size, max_size=P.size))
    Q = _q(P, xy)
    hm = op.at()["hm"] if isinstance(op, MovableOp) else op.handles[op.moving]
    for name, f in _paths(op).items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", core.ExtrapolationWarning)
            X = f(Q).reshape(-1, *op.mesh.V.shape)[0]
            X0 = f(P.copy()).reshape(-1, *op.mesh.V.shape)[0]
        assert np.array_equal(X0, op.mesh.V), (kind, name)
        assert np.allclose(X[hm], Q, rtol=0, atol=1e-12 * op.mesh.bbox_diagonal), (kind, name)


def test_old_names_warn_and_still_work():
    from defop.operator import defop as defop_mod
    from defop.operator import kernels, movable_kernels

    with pytest.warns(DeprecationWarning, match="movable_correction"):
        assert movable_kernels.finish_frame is kernels.movable_correction
    with pytest.warns(DeprecationWarning, match="frame_from_raw"):
        assert kernels.apply is kernels.frame_from_raw
    with pytest.warns(DeprecationWarning, match="beyond_bound"):
        assert kernels.beyond is kernels.beyond_bound
    op = DefOp.load(FILES / "operator-3_tps_rank3.npz")
    f = op.fast_state()
    with pytest.warns(DeprecationWarning, match="kernel_args"):
        k = defop_mod.kernel_state(op.handle_basis, f.mats)
    assert np.array_equal(k.B, f.kernel.B)
    assert (
        defop_mod.EXTRAPOLATION_FACTOR is core.EXTRAPOLATION_FACTOR and defop_mod.training_reach is core.training_reach
    )
