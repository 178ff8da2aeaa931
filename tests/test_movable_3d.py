"""Handles that move at rest in 3D: a movable handle brings its patch (one shared rest offset), the operator's
guarantees at random placements on every path, bad P refused with nothing changed, and the joint training."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import defop as dop
from defop.operator.movable import MovableOp, fit_movable, retarget
from defop.scene.placement import patch_layout, placement_regions
from defop.training.movable import sample_joint, train_movable


@pytest.fixture(scope="module")
def bar():
    """bar_3d at about 300 vertices: 4 fixed handles on the left end face, a patch of 4 moving ones on the right."""
    return dop.shapes.load("bar_3d", n_vertices=300)


@pytest.fixture(scope="module")
def regions(bar):
    return {k: placement_regions(bar, [k], radius=0.08 * bar.mesh.bbox_diagonal) for k in (4, 5, 6, 7)}


def _synthetic(shape, placement, m=24, seed=1, rank=None):
    """An operator fitted to smooth synthetic data (the guarantees hold whatever the data)."""
    idx, Q = sample_joint(shape, placement, m, seed)
    V = shape.mesh.V
    X = []
    for i, q in zip(idx, Q):
        d = q - V[placement.handles_at(i)[shape.moving]]
        X.append(V + 0.2 * np.sin(V @ d.T)[:, :3])
    op = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, np.stack(X))
    return op if rank is None else op.compress(rank=rank)


@pytest.fixture(scope="module")
def ops(bar, regions):
    return {k: (_synthetic(bar, pr), _synthetic(bar, pr, rank=4)) for k, pr in regions.items()}


def test_a_region_vertex_moves_the_whole_patch_by_one_offset(bar, regions):
    """Before: placement regions refused every 3D mesh."""
    V = bar.mesh.V
    for k, pr in regions.items():
        lay = pr.layout[0]
        assert list(pr.members[0]) == [k] + sorted({4, 5, 6, 7} - {k}) and len(pr.vertices[0]) >= 4
        assert np.array_equal(lay[:, 0], pr.vertices[0])
        shift = V[lay] - V[bar.handles[pr.members[0]]]  # (k, 4, 3): one offset per region vertex
        assert np.abs(shift - shift[:, :1]).max() < 1e-12
        g = pr.g.toarray()
        for i in range(len(lay)):
            rows = g[pr.bump_rows([lay[i, 0]])]  # one bump per member: 1 at its vertex, 0 at the others'
            assert np.array_equal(rows[:, lay[i]], np.eye(4))
            assert np.all(rows[:, bar.handles[:4]] == 0.0)
        h = pr.handles_at(pr.vertices[0][-1:])
        assert np.array_equal(h[:4], bar.handles[:4]) and np.array_equal(h[4:][pr.members[0] - 4], lay[-1])


def _paths(op, Q, P, V):
    yield "exact", op(Q, P=P)
    yield "fast", op.evaluate_fast(Q, P=P)
    yield "batch", op.evaluate_batch(Q[None], P=P)[0]
    yield "batch-call", op(np.stack([Q, Q]), P=P)[1]
    yield "point", op(Q, P=V[P])
    yield "fast-point", op.evaluate_fast(Q, P=V[P])


@hsettings(max_examples=10, deadline=None)
@given(
    anchor=st.sampled_from([4, 5, 6, 7]), i=st.integers(0, 10**6), scale=st.floats(0.0, 0.2), seed=st.integers(0, 99)
)
def test_guarantees_at_random_placements_every_path(bar, regions, ops, tmp_path_factory, anchor, i, scale, seed):
    """Prop. 2 (every handle of the moved patch on its target, the fixed ones at rest) and (8b), bit for bit, at a
    random placement of a random patch member, float64, compressed, saved and loaded, P as index or point."""
    pr = regions[anchor]
    P = pr.vertices[0][i % len(pr.vertices[0]) : i % len(pr.vertices[0]) + 1]
    hm = pr.handles_at(P)[bar.moving]
    V, rest = bar.mesh.V, bar.mesh.V[hm]
    rng = np.random.default_rng(seed)
    Q = rest + scale * rng.normal(size=3) + 0.3 * scale * rng.normal(size=rest.shape)
    fixed = bar.handles[~bar.moving]
    path = tmp_path_factory.mktemp("mov3d") / "op.npz"
    ops[anchor][1].save(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for op in (*ops[anchor], MovableOp.load(path)):
            for name, X in _paths(op, Q, P, V):
                assert np.array_equal(X[hm], Q), name  # Prop. 2, bit for bit
                assert np.array_equal(X[fixed], V[fixed]), name
                assert np.isfinite(X).all()
            for name, X in _paths(op, rest, P, V):
                assert np.array_equal(X, V), name  # (8b), bit for bit
    loaded = MovableOp.load(path)
    assert np.array_equal(loaded.placement.layout[0], pr.layout[0])
    assert np.array_equal(loaded.evaluate_fast(rest + 0.01, P=P), ops[anchor][1].evaluate_fast(rest + 0.01, P=P))


def test_retarget_moves_every_member(bar, regions):
    pr = regions[4]
    old, new = pr.vertices[0][:1], pr.vertices[0][-1:]
    V = bar.mesh.V
    Q = V[pr.handles_at(old)[bar.moving]] + 0.05
    Q2 = retarget(Q, pr, old, new)
    np.testing.assert_allclose(Q2 - V[pr.handles_at(new)[bar.moving]], 0.05, atol=1e-14)  # q − p kept


BAD = [
    ("outside", lambda V, pr, bar: np.array([int(np.argmin(V[:, 0]))]), r"outside movable handle 0's placement"),
    ("sibling", lambda V, pr, bar: np.array([bar.handles[6]]), r"it is handle 6's vertex"),
    ("fixed", lambda V, pr, bar: np.array([bar.handles[1]]), r"it is handle 1's vertex"),
    ("nan", lambda V, pr, bar: np.full((1, 3), np.nan), r"P has NaN"),
    ("off-vertex", lambda V, pr, bar: V[pr.vertices[0][:1]] + 0.01, r"not on a vertex"),
    ("2d", lambda V, pr, bar: V[pr.vertices[0][:1], :2], r"P must be \(1,\) vertex indices or \(1, 3\)"),
    ("two", lambda V, pr, bar: pr.vertices[0][:2], r"P must be \(1,\)"),
    ("deep", lambda V, pr, bar: V[pr.vertices[0][:1]][None], r"P must be"),
    ("index-range", lambda V, pr, bar: np.array([10**6]), r"the mesh has \d+ vertices"),
]


@pytest.mark.parametrize("name,make,match", BAD, ids=[b[0] for b in BAD])
def test_bad_placement_refused_nothing_changed(bar, regions, ops, name, make, match):
    pr = regions[4]
    op = ops[4][1]
    good = pr.vertices[0][-1:]
    Q = op.placement.mesh.V[pr.handles_at(good)[bar.moving]] + 0.02
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        before, st0 = op.evaluate_fast(Q, P=good), op.at(good)
        for f in (op, op.evaluate_fast, op.evaluate_batch, op.at):
            with pytest.raises(ValueError, match=match):
                f(Q[None] if f == op.evaluate_batch else Q, P=make(bar.mesh.V, pr, bar)) if f != op.at else f(
                    make(bar.mesh.V, pr, bar)
                )
        assert op.at(good) is st0 and np.array_equal(op.evaluate_fast(Q, P=good), before)


def test_regions_that_cannot_carry_the_patch_are_refused(bar, regions):
    pr = regions[4]
    V = bar.mesh.V
    near = np.flatnonzero(np.linalg.norm(V - V[bar.handles[4]], axis=1) < 0.15)
    lay, exact = patch_layout(bar.mesh, bar.handles, pr.members[0], near)
    assert exact.any() and not exact.all()  # past the end face the patch would leave the bar
    assert np.isin(near[exact], pr.vertices[0]).any() and not np.isin(near[~exact], pr.vertices[0]).any()
    with pytest.raises(ValueError, match=rf"region 0: at vertex {near[~exact][0]} the patch .* not sit on mesh"):
        placement_regions(bar, [4], vertices=[np.union1d(pr.vertices[0], near[~exact][:1])])
    with pytest.raises(ValueError, match="in one patch"):
        placement_regions(bar, [4, 6], radius=0.05)


def test_two_patches_on_the_tet_octopus():
    """Two movable patches of one handle each on the tet octopus: P of one in the other's region is refused by
    name, and the guarantees hold at both."""
    s = dop.shapes.load("octopus_3d", n_vertices=1000)
    pr = placement_regions(s, [0, 3], radius=0.05 * s.mesh.bbox_diagonal)
    op = _synthetic(s, pr, m=16, rank=4)
    V = s.mesh.V
    with pytest.raises(ValueError, match=r"P\[1\] is vertex \d+, outside .* it is in movable handle 0's patch region"):
        op.at(np.array([pr.vertices[0][0], pr.vertices[0][-1]]))
    P = np.array([pr.vertices[0][-1], pr.vertices[1][-1]])
    hm = pr.handles_at(P)[s.moving]
    Q = V[hm] + 0.02 * np.random.default_rng(0).normal(size=(len(hm), 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        for name, X in _paths(op, Q, P, V):
            assert np.array_equal(X[hm], Q), name
            assert np.array_equal(op(V[hm], P=P), V)


def test_train_movable_on_bar_3d(bar, regions):
    """The joint training on bar_3d: truth solved with the patch moved, the operator exact at its samples'
    handles and at rest, and on the truth at a training sample (Prop. 1 on the interpolating path, every joint point a
    centre: 20 samples, more than the 16 affine terms of Ψ on R^15)."""
    pr = regions[4]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, rec = train_movable(bar, pr, m=20, seed=0, n_jobs=1, progress=False, centres=None)
    assert rec.converged.all() and op.meta["n_samples"] == 20
    hm = pr.handles_at(rec.idx[0])[bar.moving]
    np.testing.assert_allclose(rec.X[0][hm], rec.Q[0], atol=1e-12)  # the truth holds the moved patch
    X = op(rec.Q[0], P=rec.idx[0])
    assert np.abs(X - rec.X[0]).max() < 1e-6 * bar.mesh.bbox_diagonal  # Prop. 1 at a training pair
    assert np.array_equal(op(bar.mesh.V[hm], P=rec.idx[0]), bar.mesh.V)


def _edited(src, dst, drop=(), **arrays):
    """A copy of the operator file ``src`` with arrays replaced or dropped."""
    with np.load(src) as z:
        data = {k: z[k] for k in z.files if k not in drop}
    data.update(arrays)
    with open(dst, "wb") as fh:
        np.savez(fh, **data)
    return dst


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (dict(drop=("placement_member_sizes",)), r"placement_members and placement_member_sizes come together"),
        (dict(placement_members=np.array([4, 5, 6, 1])), r"members\[0\] must be moving handles"),
        (dict(placement_members=np.array([4.0, 5.0, 6.0, 7.0])), r"'placement_members' must be 1-D of kind 'iu'"),
        (dict(placement_member_sizes=np.array([3])), r"placement_member_sizes must be positive and sum"),
        (dict(drop=("placement_members", "placement_member_sizes")), r"handle 5 .* lies inside placement region 0"),
    ],
)
def test_damaged_patch_files_are_refused(ops, tmp_path, edit, match):
    """A 3D movable file whose patches are damaged or missing is refused naming the file and the array."""
    from defop.operator.io import OperatorFileError

    path = tmp_path / "m.npz"
    ops[4][1].save(path)
    with np.load(path) as z:
        assert z["placement_members"].tolist() == [4, 5, 6, 7] and z["placement_member_sizes"].tolist() == [4]
    bad = _edited(path, tmp_path / "bad.npz", **edit)
    with pytest.raises(OperatorFileError, match=r"bad\.npz.*" + match):
        MovableOp.load(bad)


def test_the_default_frame_in_3d_is_the_one_rule(bar, regions):
    """The 3D joint operator takes the default of every dimension, read from the data (benchmarks/README.md,
    2026-12-02 fourth part: on bar_3d at the budget it meets the frame and error targets, and at the fixed-P
    tolerance its rank, not Ψ, set the old floor): m + 1 TPS centres over z of (b + n) rows of 3, and the joint
    compression tolerance, looser than the fixed-P one, so the factors keep fewer rows."""
    from defop.operator import compress
    from defop.operator import movable as mv

    m = 40
    op = _synthetic(bar, regions[4], m=m)
    assert op.basis.centers.shape == (m + 1, 1 + 4, 3) and op.meta["n_centres"] == m + 1
    kernel = op.compress().fast_state().kernel
    assert kernel.tps[0].shape == ((1 + 4) * 3, m + 1)  # the frame's distances: one column per centre
    same = _synthetic(bar, regions[4], m=m).compress(tol=mv.COMPRESS_TOL)
    assert all(np.array_equal(a, b) for a, b in zip(op.factors, same.factors, strict=True))
    assert op.rank < _synthetic(bar, regions[4], m=m).compress(tol=compress.TOL).rank
