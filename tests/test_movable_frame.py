"""MovableOp's frame: P checked and resolved once per placement, Q checked in full only when the compiled frame's
guard or reach bound asks; the same bits, warnings and errors as a frame with nothing kept."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import defop as dop
from defop.operator import core
from defop.operator.movable import MovableOp, fit_movable
from defop.scene.placement import SNAP_TOL, placement_regions
from defop.training.movable import sample_joint


@pytest.fixture(scope="module")
def setup():
    """A 1.5 x 1 rectangle: one movable handle of two moving ones and a fixed one; an operator fitted to smooth
    synthetic data (the guarantees and the caching do not depend on the data)."""
    outer = np.array([[0.0, 0.0], [1.5, 0.0], [1.5, 1.0], [0.0, 1.0]])
    H = np.array([[1.3, 0.5], [0.7, 0.8], [0.1, 0.5]])
    shape = dop.shapes.from_polygon(
        outer,
        handles=H,
        moving=[True, True, False],
        n_vertices=160,
        name="rect-frame",
        regions=[{"kind": "disc", "radius": 0.1}] * 2,
    )
    placement = placement_regions(shape, [1], radius=0.12)
    idx, Q = sample_joint(shape, placement, 24, 3)
    V = shape.mesh.V
    X = np.stack([V + 0.2 * np.cos(3 * V + (q - V[shape.handles[:2]]).sum()) * (q - q.mean(0)).sum() for q in Q])
    op = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X)
    return shape, placement, op


def fresh(op):
    """The same operator with no placement kept: its first frame checks and resolves everything."""
    new = MovableOp(op.mesh, op.handles, op.moving, op.placement, op.basis, op.W, op.scales, op.meta, op.reach)
    return new.set_factors(op.factors)


def kernels_apart(op, Q, P):
    """The frame by the two kernels called one after the other (the arithmetic before they were fused)."""
    s, f = op.at(P), op.fast_state()
    k, b = f.kernel, len(s.idx)
    z = s.z0.copy()
    z[b:] = (Q - s.P) / op.scales[1]
    x = op.mesh.V.ravel()
    Xz, _ = k.lib.tps_frame(z, np.zeros_like(z), f.R2, k.far2, *k.tps, k.A, k.B, x, np.empty(0, np.int64), np.empty(0))
    if not Xz.size:
        return None
    return k.lib.movable_correction(Xz, s.X0, x, Q, s.P, s.idx, s.rows, s.hm, *s.bumps, s.fixed).reshape(-1, 2)


def frame_and_warnings(f, *args, **kwargs):
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        X = f(*args, **kwargs)
    return X, [str(w.message) for w in got]


@hsettings(max_examples=25, deadline=None)
@given(
    i=st.integers(0, 10**6),
    as_point=st.booleans(),
    scale=st.one_of(st.just(0.0), st.floats(0.0, 2.5)),
    seed=st.integers(0, 99),
    kind=st.sampled_from(["float32", "float64", "exact"]),
)
def test_kept_placement_is_bit_for_bit_the_fresh_frame(setup, i, as_point, scale, seed, kind):
    shape, placement, op = setup
    op = fresh(op) if kind == "exact" else fresh(op).compress(rank=3, dtype=np.dtype(kind))
    verts = placement.vertices[0]
    v = verts[i % len(verts)]
    rng = np.random.default_rng(seed)
    P = np.array([v])
    if as_point:  # within the snapping tolerance of vertex v
        P = shape.mesh.V[P] + 0.3 * SNAP_TOL * shape.mesh.bbox_diagonal * rng.uniform(-1, 1, (1, 2)) / np.sqrt(2)
    hm = placement.handles_at(np.array([v]))[shape.moving]
    rest = shape.mesh.V[hm]
    u = rng.normal(size=rest.shape)
    Q = rest + 1.5 * scale * op.reach[:, None] * u / np.linalg.norm(u, axis=1, keepdims=True)
    op.evaluate_fast(rest + 0.01, P=P)  # the placement is kept
    X, said = frame_and_warnings(op.evaluate_fast, Q, P=P)
    X1, said1 = frame_and_warnings(fresh(op).evaluate_fast, Q, P=P)
    assert np.array_equal(X, X1) and said == said1
    _, said_call = frame_and_warnings(fresh(op), Q, P=P)  # the full check of Q: the same warnings
    assert said == said_call
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        assert np.array_equal(X, op.evaluate_fast(Q, P=np.array([v])))  # P as a vertex: the same frame
    assert np.array_equal(X[hm], Q) and np.array_equal(X[shape.handles[2]], shape.mesh.V[shape.handles[2]])
    assert np.array_equal(op.evaluate_fast(rest, P=P), shape.mesh.V)  # (8b) at the kept placement
    apart = kernels_apart(op, Q, P)
    assert apart is None or np.array_equal(X, apart)


BAD_Q = {
    "nan": lambda r: r + np.nan,
    "inf": lambda r: r + np.array([[0.0, np.inf], [0.0, 0.0]]),
    "shape": lambda r: np.vstack([r, r]),
    "batch": lambda r: r[None],
    "complex": lambda r: r + 1j,
    "strings": lambda r: [["a", "b"], ["c", "d"]],
    "ragged": lambda r: [[0.0, 1.0], [0.0]],
    "not finite psi": lambda r: r + 1e300,
}


@pytest.mark.parametrize("bad", sorted(BAD_Q))
@pytest.mark.parametrize("kind", ["float32", "exact"])
def test_bad_Q_after_a_kept_placement_raises_the_same_clear_error(setup, bad, kind):
    shape, placement, op = setup
    op = fresh(op) if kind == "exact" else fresh(op).compress(rank=3)
    P = shape.mesh.V[placement.vertices[0][:1]]
    rest = op.at(P).P
    Qbad = BAD_Q[bad](rest)
    errors = []
    for o in (fresh(op), op):
        o.evaluate_fast(rest + 0.01, P=P)  # a good frame: the placement is kept (for the fresh one, too)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
            with pytest.raises(ValueError, match="Q") as e:
                o.evaluate_fast(Qbad, P=P)
        errors.append(str(e.value))
        assert np.array_equal(o.evaluate_fast(rest, P=P), shape.mesh.V)  # nothing changed
    assert errors[0] == errors[1]


def test_a_frame_resolves_P_once_and_checks_Q_in_full_only_when_asked(setup, monkeypatch):
    """Before: every frame resolved P given as points (the region lookup: 9x a frame) and ran the full check of Q."""
    shape, placement, op = setup
    op = fresh(op).compress(rank=3)
    calls = {"resolve": 0, "check": 0}
    resolve, check = placement.resolve, core.check_configurations

    def counted(name, f):
        def g(*a, **k):
            calls[name] += 1
            return f(*a, **k)

        return g

    monkeypatch.setattr(placement, "resolve", counted("resolve", resolve))
    monkeypatch.setattr(core, "check_configurations", counted("check", check))
    P = shape.mesh.V[placement.vertices[0][2:3]] + 1e-9
    rest = op.at(P).P
    assert calls["resolve"] == 1
    for t in np.linspace(0.0, 0.02, 20):
        op.evaluate_fast(rest + t, P=P.copy())  # another array of the same bits: the same placement
    assert calls == {"resolve": 1, "check": 0}
    with pytest.warns(dop.operator.ExtrapolationWarning, match="from its rest position P"):
        op.evaluate_fast(rest + 3 * op.reach.max(), P=P)  # beyond the kernel's reach bound: the full check
    assert calls == {"resolve": 1, "check": 1}
    with pytest.raises(ValueError, match="not on a vertex"):
        op.evaluate_fast(rest, P=P + 0.05)  # a changed P is checked again
    assert calls["resolve"] == 2


def test_fewer_centres_keep_the_guarantees(setup):
    """fit_movable(centres=k): k TPS functions picked farthest first from the nominal rest, the other joint points
    fitted by least squares; handles and rest pose stay exact bit for bit."""
    shape, placement, op = setup
    idx, Q = sample_joint(shape, placement, 24, 3)
    V = shape.mesh.V
    X = np.stack([V + 0.05 * np.sin(V.sum(1, keepdims=True) + q.sum()) for q in Q])
    few = fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X, centres=12)
    assert few.basis.size < op.basis.size and few.meta["n_centres"] == 12
    assert np.array_equal(few.basis.centers[0], np.zeros_like(few.basis.centers[0]))  # the nominal rest first
    P = placement.vertices[0][-1:]
    rest = V[placement.handles_at(P)[shape.moving]]
    for o in (few, fresh(few).compress(rank=3)):
        for f in (o, o.evaluate_fast):
            X1 = f(rest + 0.02, P=P)
            assert np.array_equal(X1[placement.handles_at(P)[shape.moving]], rest + 0.02)
            assert np.array_equal(f(rest, P=P), V)
    with pytest.raises(ValueError, match="centres"):
        fit_movable(shape.mesh, shape.handles, shape.moving, placement, idx, Q, X, centres=0)
