"""MovableOp's default frame: one TPS centre per training sample (fit.centre_count) and the joint compression
tolerance (movable.COMPRESS_TOL), and the per-placement state never stale whatever sequence of P (as vertices,
points, None, an array changed in place) and factors. The guarantees on the default path at random placements:
tests/test_movable.py::test_guarantees_every_path."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import defop as dop
from defop.operator import fit
from defop.operator import movable as mv
from defop.operator.movable import MovableOp, fit_movable
from defop.scene.placement import placement_regions
from defop.training.movable import sample_joint

M = 30


@pytest.fixture(scope="module")
def setup():
    """A 1.5 x 1 rectangle: two movable handles of three moving ones and a fixed one, an operator fitted by default
    to smooth synthetic data at M joint samples (the guarantees and the state do not depend on the data)."""
    outer = np.array([[0.0, 0.0], [1.5, 0.0], [1.5, 1.0], [0.0, 1.0]])
    H = np.array([[1.3, 0.5], [0.7, 0.8], [0.4, 0.2], [0.1, 0.5]])
    shape = dop.shapes.from_polygon(
        outer,
        handles=H,
        moving=[True, True, True, False],
        n_vertices=180,
        name="rect-default",
        regions=[{"kind": "disc", "radius": 0.1}] * 3,
    )
    placement = placement_regions(shape, [0, 1], radius=0.12)
    idx, Q = sample_joint(shape, placement, M, 5)
    V = shape.mesh.V
    X = np.stack([V + 0.2 * np.cos(3 * V + (q - V[shape.handles[:3]]).sum()) * (q - q.mean(0)).sum() for q in Q])
    op = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X)
    return shape, placement, op, (idx, Q, X)


def fresh(op):
    """The same operator and factors with no placement kept."""
    new = MovableOp(op.mesh, op.handles, op.moving, op.placement, op.basis, op.W, op.scales, op.meta, op.reach)
    return new.set_factors(op.factors)


def test_default_is_one_centre_per_sample_and_the_joint_tolerance(setup):
    shape, placement, op, (idx, Q, X) = setup
    assert len(op.basis.centers) == M + 1 == op.meta["n_centres"]  # the old default kept every joint point
    assert not op.basis.centers[0].any()  # the nominal rest is a centre (its fit exact)
    full = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X, centres=None)
    assert len(full.basis.centers) == M + op.meta["n_rest_centres"] > M + 1  # every joint point
    count = fit.centre_count
    assert count("auto", M, 10) == 10 and count(None, M, 99) == 99 and count(7, M, 99) == 7
    with pytest.raises(ValueError, match="centres"):
        count("some", M, 99)
    a = fresh(op).compress()
    b = fresh(op).compress(tol=mv.COMPRESS_TOL)
    assert mv.COMPRESS_TOL > fit_tol()  # looser than the fixed-P default
    assert a.rank == b.rank and all(np.array_equal(x, y) for x, y in zip(a.factors, b.factors))


def fit_tol():
    from defop.operator.compress import TOL

    return TOL


step = st.tuples(
    st.sampled_from(["index", "point", "none", "in-place", "factors"]),
    st.integers(0, 10**6),
    st.integers(0, 10**6),
    st.floats(0.0, 0.3),
)


@hsettings(max_examples=15, deadline=None)
@given(steps=st.lists(step, min_size=2, max_size=12))
def test_kept_placements_are_never_stale(setup, steps):
    """Each frame of a sequence of P (and factors) equals a fresh operator's at that P, bit for bit: the kept
    state follows P as given (an array changed in place included) and is dropped with the factors."""
    shape, placement, op, _ = setup
    op = fresh(op).compress()
    vs, V = placement.vertices, shape.mesh.V
    buf = np.array([vs[0][0], vs[1][0]])  # one array, changed in place between frames (an editor's buffer)
    rng = np.random.default_rng(len(steps))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for kind, i, j, scale in steps:
            if kind == "factors":
                op.compress(rank=1 + i % 4)
                continue
            idx = np.array([vs[0][i % len(vs[0])], vs[1][j % len(vs[1])]])
            if kind == "in-place":
                buf[:] = idx
            P = {"index": idx, "point": V[idx], "none": None, "in-place": buf}[kind]
            want = placement.nominal if kind == "none" else idx
            assert np.array_equal(op.at(P).idx, want)
            hm = placement.handles_at(want)[shape.moving]
            Q = V[hm] + scale * rng.normal(size=(len(hm), 2))
            ref = fresh(op)
            assert np.array_equal(op.evaluate_fast(Q, P=P), ref.evaluate_fast(Q, P=P))
            assert np.array_equal(op(Q, P=P), ref(Q, P=P))
            assert np.array_equal(op.evaluate_fast(Q, P=P)[hm], Q)
