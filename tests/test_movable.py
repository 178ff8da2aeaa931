"""Handles that move at rest (issue 38): placement regions, D(x; P, Q) and its guarantees on every path, files."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import defop as dop
from defop.operator.io import OperatorFileError
from defop.operator.movable import MovableOp, fit_movable, residual, retarget
from defop.operator.movable_carry import CarryOp
from defop.scene.placement import SNAP_TOL, placement_regions
from defop.training.movable import sample_joint, shape_at, solve_joint, train_movable


@pytest.fixture(scope="module")
def shape(movable_rect):
    """The 2 x 1 rectangle of tests/conftest.py, about 250 vertices: two moving handles (movable) and one fixed."""
    return movable_rect(250)


@pytest.fixture(scope="module")
def placement(shape):
    return placement_regions(shape, [0, 1], radius=0.15)


@pytest.fixture(scope="module")
def trained(shape, placement, tmp_path_factory):
    import os

    os.environ.setdefault("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, rec = train_movable(shape, placement, m=40, seed=0, n_jobs=1, progress=False)
    return op, rec


def _synthetic(shape, placement, m=30, seed=1):
    """An operator fitted to smooth synthetic data (the guarantees hold whatever the data)."""
    idx, Q = sample_joint(shape, placement, m, seed)
    V = shape.mesh.V
    X = np.stack([V + 0.3 * np.sin(V @ (q - V[shape.handles[shape.moving]]).T)[:, :2] for q in Q])
    return fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X)


def test_regions(shape, placement):
    g = placement.g.toarray()
    assert all(len(v) >= 5 and h in v for v, h in zip(placement.vertices, placement.nominal))
    assert not np.intersect1d(*placement.vertices).size
    for ell, verts in enumerate(placement.vertices):
        rows = g[placement.offset[ell] : placement.offset[ell + 1]]
        assert np.array_equal(rows[np.arange(len(verts)), verts], np.ones(len(verts)))
        others = np.concatenate([v for j, v in enumerate(placement.vertices) if j != ell] + [shape.handles[2:]])
        assert np.all(rows[:, others] == 0.0)
    assert np.all((g >= 0) & (g <= 1))


def test_bad_regions(shape):
    with pytest.raises(ValueError, match="overlap"):
        placement_regions(shape, [0, 1], radius=0.7)
    with pytest.raises(ValueError, match="fixed"):
        placement_regions(shape, [2], radius=0.1)
    with pytest.raises(ValueError, match="another handle"):
        placement_regions(shape, [1], vertices=[np.array([shape.handles[1], shape.handles[2]])])
    with pytest.raises(ValueError, match="nominal vertex"):
        placement_regions(shape, [0], vertices=[np.array([0])])
    with pytest.raises(ValueError, match="radius"):
        placement_regions(shape, [0], radius=-1.0)
    with pytest.raises(ValueError, match="exactly one"):
        placement_regions(shape, [0])


def test_a_vertex_outside_the_region_is_refused_not_moved_elsewhere(shape, placement):
    """Vertices given directly (fit_movable's idx, retarget, handles_at) are checked against the region: a vertex
    outside it, or past its last vertex, was read as another region vertex (the nominal one) with no error."""
    inside = set(np.concatenate(placement.vertices).tolist())
    outside = next(v for v in range(shape.mesh.n_vertices) if v not in inside and v not in set(shape.handles))
    bad = placement.nominal.copy()
    bad[0] = outside
    for idx in (bad, np.full(placement.n_movable, shape.mesh.n_vertices + 7)):
        with pytest.raises(ValueError, match="not in movable handle 0's placement region"):
            placement.handles_at(idx)
        with pytest.raises(ValueError, match="placement region"):
            retarget(shape.P_moving, placement, placement.nominal, idx)
    Q = shape.P_moving[None] + 0.01
    X = np.repeat(shape.mesh.V[None], 1, axis=0)
    with pytest.raises(ValueError, match="placement region"):
        fit_movable(shape.mesh, shape.handles, shape.moving, placement, bad[None], Q, X)


def test_3d_region_moves_the_handle_patch():
    """A 3D movable handle brings its patch (tests/test_movable_3d.py has the operator's guarantees)."""
    s = dop.shapes.load("bar_3d", n_vertices=300)
    pr = placement_regions(s, [4], radius=0.08 * s.mesh.bbox_diagonal)
    assert list(pr.members[0]) == [4, 5, 6, 7] and len(pr.vertices[0]) > 1
    with pytest.raises(ValueError, match="in one patch"):
        placement_regions(s, [4, 5], radius=0.08 * s.mesh.bbox_diagonal)


def _paths(op, Q, P):
    yield "exact", op(Q, P=P)
    yield "fast", op.evaluate_fast(Q, P=P)
    yield "batch", op.evaluate_batch(Q[None], P=P)[0]
    yield "batch-call", op(np.stack([Q, Q]), P=P)[1]


@hsettings(max_examples=12, deadline=None)
@given(i=st.integers(0, 10**6), j=st.integers(0, 10**6), scale=st.floats(0.0, 0.3), seed=st.integers(0, 99))
def test_guarantees_every_path(shape, placement, i, j, scale, seed):
    op = _synthetic(shape, placement)  # the default fit: one centre per sample
    P = np.array(
        [placement.vertices[0][i % len(placement.vertices[0])], placement.vertices[1][j % len(placement.vertices[1])]]
    )
    hm = placement.handles_at(P)[shape.moving]
    rest = shape.mesh.V[hm]
    Q = rest + scale * np.random.default_rng(seed).normal(size=rest.shape)
    fixed = shape.handles[~shape.moving]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for compress in (None, {"rank": 3}, {}):  # float64 W_F, rank 3, the default (COMPRESS_TOL)
            if compress is not None:
                op.compress(**compress)
            for name, X in _paths(op, Q, P):
                assert np.array_equal(X[hm], Q), name  # Prop. 2, bit for bit
                assert np.array_equal(X[fixed], shape.mesh.V[fixed]), name
                assert np.isfinite(X).all()
            for name, X in _paths(op, rest, P):
                assert np.array_equal(X, shape.mesh.V), name  # (8b), bit for bit
            assert np.array_equal(op(rest, P=shape.mesh.V[P]), shape.mesh.V)  # P as points
            assert np.array_equal(op.evaluate_fast(Q, P=shape.mesh.V[P])[hm], Q)


def test_training_reproduced_and_truth(shape, placement, trained):
    op, rec = trained
    assert rec.converged.all()
    diag = shape.mesh.bbox_diagonal
    full = fit_movable(shape.mesh, shape.handles, shape.moving, placement, rec.idx, rec.Q, rec.X, centres=None)
    assert op.basis.size < full.basis.size  # the default: one centre per sample, fewer than the joint points
    for k in range(0, 40, 7):  # Prop. 1: with every joint point a centre the TPS interpolates every training pair
        assert np.abs(full(rec.Q[k], P=rec.idx[k]) - rec.X[k]).max() < 1e-8 * diag
    idx, Q = sample_joint(shape, placement, 4, 123)
    X, conv = solve_joint(shape, placement, idx, Q, n_jobs=1, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        errs = [np.abs(op(q, P=i) - x).max() / diag for i, q, x in zip(idx, Q, X)]
        assert max(errs) < 0.05, errs
        assert residual(op, Q[0], idx[0]) < 0.05
        carry = CarryOp(
            dop.train(shape_at(shape, placement, placement.nominal), m=12, n_jobs=1, progress=False)[0], placement
        )
        Xc = carry(Q[0], P=idx[0])
    hm = placement.handles_at(idx[0])[shape.moving]
    assert np.array_equal(Xc[hm], Q[0])
    assert np.array_equal(carry(shape.mesh.V[hm], P=idx[0]), shape.mesh.V)


def test_save_load_bit_for_bit(shape, placement, tmp_path):
    op = _synthetic(shape, placement)
    P = np.array([placement.vertices[0][3], placement.vertices[1][-1]])
    Q = shape.mesh.V[placement.handles_at(P)[shape.moving]] + 0.05
    for compressed in (False, True):
        if compressed:
            op.compress(rank=4)
        op.save(tmp_path / "m.npz")
        back = MovableOp.load(tmp_path / "m.npz")
        assert np.array_equal(back.W, op.W) and back.scales == op.scales and back.meta == op.meta
        for (_, a), (_, b) in zip(_paths(op, Q, P), _paths(back, Q, P)):
            assert np.array_equal(a, b)
        assert [np.array_equal(a, b) for a, b in zip(back.placement.vertices, placement.vertices)] == [True, True]
    with pytest.raises(OperatorFileError, match="movable-handle operator file"):
        dop.DefOp.load(tmp_path / "m.npz")
    Qs = shape.mesh.V[shape.handles[shape.moving]] + 0.05 * np.random.default_rng(0).normal(size=(6, 2, 2))
    op0 = dop.operator.fit.fit_shape(shape, Qs, np.stack([shape.mesh.V] * 6), basis="linear")
    op0.save(tmp_path / "d.npz")
    with pytest.raises(OperatorFileError, match="single-valued operator file.*use DefOp.load"):
        MovableOp.load(tmp_path / "d.npz")


def test_bad_inputs(shape, placement):
    op = _synthetic(shape, placement)
    rest = shape.mesh.V[shape.handles[shape.moving]]
    off = np.setdiff1d(np.arange(shape.mesh.n_vertices), np.concatenate(placement.vertices))[0]
    with pytest.raises(ValueError, match="outside movable handle 0"):
        op(rest, P=np.array([off, placement.nominal[1]]))
    with pytest.raises(ValueError, match="outside movable handle 1"):
        op(rest, P=np.array([placement.nominal[0], placement.nominal[0]]))  # two handles on one vertex
    pts = shape.mesh.V[placement.nominal] + [[0.5 * SNAP_TOL * shape.mesh.bbox_diagonal, 0], [0, 0]]
    assert np.array_equal(op(rest, P=pts), shape.mesh.V)  # snapped within the tolerance
    with pytest.raises(ValueError, match="not on a vertex"):
        op(rest, P=shape.mesh.V[placement.nominal] + [[1e-3, 0], [0, 0]])
    with pytest.raises(ValueError, match="vertex indices"):
        op(rest, P=np.zeros(3, int))
    with pytest.raises(ValueError, match="NaN"):
        op(rest + np.nan, P=None)
    with pytest.raises(ValueError, match="NaN"):
        op(rest, P=np.full((2, 2), np.nan))
    with pytest.warns(dop.operator.ExtrapolationWarning, match="from its rest position P"):
        op(rest + 5.0)
    state = op.at(None)["idx"].copy()
    with pytest.raises(ValueError):
        op(rest, P=np.array([off, off]))
    assert np.array_equal(op.at(None)["idx"], state)  # nothing changed


def test_retarget_keeps_displacement(shape, placement):
    old = placement.nominal
    new = np.array([placement.vertices[0][0], placement.vertices[1][1]])
    Q = shape.mesh.V[shape.handles[shape.moving]] + [[0.1, 0.0], [0.0, -0.1]]
    Q2 = retarget(Q, placement, old, new)
    rows = placement.moving_rows()
    np.testing.assert_allclose(Q2[rows] - shape.mesh.V[new], Q[rows] - shape.mesh.V[old], atol=1e-15)


def test_retarget_at_rest_lands_exactly_on_the_new_rest_handles():
    """Undeformed handles moved to other region vertices are the new rest positions bit for bit, so the rest pose
    stays exact (8b) after a move in the editor or the page: q + (p' - p) was one ulp off p' for 181 of the aleph's
    15,373 pairs of region vertices."""
    aleph = dop.shapes.load("aleph")
    regions = placement_regions(aleph, [0, 1], radius=0.05 * aleph.mesh.bbox_diagonal)
    V, first, nominal = aleph.mesh.V, regions.vertices[0][:60], regions.nominal
    for a in first:
        for b in first:
            old, new = np.array([a, nominal[1]]), np.array([b, nominal[1]])
            Q = retarget(V[regions.handles_at(old)[aleph.moving]], regions, old, new)
            assert np.array_equal(Q, V[regions.handles_at(new)[aleph.moving]]), (a, b)


def test_batch_rows_at_rest_are_exact_and_far_rows_finite(shape, placement):
    op = _synthetic(shape, placement)
    P = np.array([placement.vertices[0][1], placement.vertices[1][2]])
    rest = shape.mesh.V[placement.handles_at(P)[shape.moving]]
    Qs = np.stack([rest, rest + 0.05, rest, rest - 0.02])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for compressed in (False, True):
            if compressed:
                op.compress(rank=2, dtype=np.float64)
            for X in (op(Qs, P=P), op.evaluate_batch(Qs, P=P)):
                assert np.array_equal(X[0], shape.mesh.V) and np.array_equal(X[2], shape.mesh.V)
                assert np.array_equal(X[:, placement.handles_at(P)[shape.moving]], Qs)
        X = op.evaluate_fast(rest + 1e6, P=P)  # beyond the float32 guard: the scaled numpy product
        assert np.isfinite(X).all() and np.array_equal(X[placement.handles_at(P)[shape.moving]], rest + 1e6)


def test_placement_regions_are_part_of_the_cache_key(shape, placement, tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    other = placement_regions(shape, [0, 1], radius=0.12)
    idx = np.stack([other.nominal, other.nominal])
    Q = np.stack([shape.mesh.V[shape.handles[shape.moving]] + 0.01] * 2)
    solve_joint(shape, placement, idx, Q, n_jobs=1, progress=False)
    n = len(list(tmp_path.rglob("*.npz")))
    solve_joint(shape, placement, idx, Q, n_jobs=1, progress=False)  # a hit: nothing new
    assert len(list(tmp_path.rglob("*.npz"))) == n
    solve_joint(shape, other, idx, Q, n_jobs=1, progress=False)  # other regions: another entry
    assert len(list(tmp_path.rglob("*.npz"))) == n + 1


def _edited(src, dst, header=None, **arrays):
    """A copy of the operator file ``src`` with header fields and arrays replaced."""
    import json

    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    h = json.loads(str(data["header"]))
    h.update(header or {})
    data.update(arrays, header=np.array(json.dumps(h)))
    with open(dst, "wb") as fh:
        np.savez(fh, **data)
    return dst


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (dict(header={"dim": 3}), r"dim = 3, but V is"),
        (dict(header={"dim": "2"}), r"dim must be an integer"),
        (dict(placement_movable=np.array([0.5, 1.5])), r"'placement_movable' must be 1-D of kind 'iu'"),
        (dict(placement_vertices=np.array([0.0, 1.0])), r"'placement_vertices' must be 1-D of kind 'iu'"),
        (dict(placement_reach=np.array([-0.1, 0.2])), r"reach must be 2 positive finite lengths"),
        (dict(reach=np.array([-0.1, 0.2])), r"'reach' must be 2 non-negative finite lengths"),
    ],
)
def test_damaged_movable_files_are_refused(shape, placement, tmp_path, edit, match):
    """Header fields and arrays that loaded silently (a 3D header on a 2D mesh, fractional region vertices, negative
    reaches that made the extrapolation warning fire at rest): refused, naming the file (review of issue 38)."""
    op = _synthetic(shape, placement)
    op.save(tmp_path / "m.npz")
    bad = _edited(tmp_path / "m.npz", tmp_path / "bad.npz", **edit)
    with pytest.raises(OperatorFileError, match=r"bad\.npz.*" + match):
        MovableOp.load(bad)


def test_region_vertices_and_reach_are_checked(shape):
    """Fractional vertex indices were truncated (1.5 -> vertex 1) and a negative or NaN reach raised scipy's
    'limit must be >= 0': both are now a ValueError naming the argument (review of issue 38)."""
    h = int(shape.handles[0])
    with pytest.raises(ValueError, match=r"placement region 0 must hold integer vertex indices.*1\.5"):
        placement_regions(shape, [0], vertices=[np.array([float(h), 1.5])])
    for reach in ([-1.0], [np.nan], [1.0, 2.0]):
        with pytest.raises(ValueError, match=r"reach must be 1 positive finite lengths"):
            placement_regions(shape, [0], radius=0.1, reach=reach)
    ok = placement_regions(shape, [0], vertices=[np.array([float(h)])])  # integral floats stay accepted
    assert ok.vertices[0].tolist() == [h]


def test_train_movable_refuses_before_any_solve(shape, placement):
    """n_q = 0 raised a ZeroDivisionError, a placement made for another mesh an IndexError from deep in the
    sampling, and movable=[0.5] was truncated to handle 0: each is now a ValueError naming the argument (review of
    issue 38)."""
    other = dop.shapes.from_polygon(
        np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.5], [0.0, 1.5]]),
        handles=np.array([[2.7, 0.75], [1.5, 1.2], [0.15, 0.75]]),
        moving=[True, True, False],
        n_vertices=150,
        name="rect2",
    )
    with pytest.raises(ValueError, match=r"n_q must be an integer >= 1, got 0"):
        train_movable(shape, placement, m=5, n_q=0, n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match=r"placement .*'rect2'"):
        train_movable(other, placement, m=5, n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match=r"placement must be .*PlacementRegions"):
        train_movable(shape, [0, 1], m=5, n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match=r"movable\[0\] must be an integer.*0\.5"):
        placement_regions(shape, [0.5], radius=0.1)


def test_carry_op_lives_in_movable_carry_alone():
    """CarryOp moved to defop.operator.movable_carry, which imports defop.operator.movable (not the other way: no
    import cycle)."""
    from defop.operator import movable, movable_carry

    assert movable_carry.CarryOp is CarryOp and not hasattr(movable, "CarryOp")
