"""The reach (per moving handle, the distance from rest to its farthest training sample) has one home (issue 35):
:func:`defop.operator.defop.training_reach`. The DefOp's extrapolation warning, the editor's discs
(:func:`defop.editor.logic.reach_polygons`) and the page's payload (:func:`defop.editor.payload.region_balls`,
:func:`defop.editor.payload.defop_to_payload`) read it from there and agree."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.editor.logic import reach_polygons
from defop.editor.payload import defop_to_payload, region_balls
from defop.operator.defop import EXTRAPOLATION_FACTOR, ExtrapolationWarning, training_reach


def _disc_radii(P, polygons):
    """The radius of each handle's disc (its polygon's distance from P; NaN where there is none)."""
    return np.array([np.linalg.norm(polys[0] - p, axis=1).max() if polys else np.nan for p, polys in zip(P, polygons)])


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 4), m=st.integers(0, 6), d=st.sampled_from([2, 3]), seed=st.integers(0, 2**16))
def test_the_editor_and_the_payload_draw_the_operators_reach(n, m, d, seed):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, d))
    samples = P + rng.normal(scale=rng.uniform(0.01, 10), size=(m, n, d))
    reach = training_reach(P, samples)
    balls = region_balls(P, None, samples)
    if m < 2:
        assert reach is None and all(b == [] for b in balls)
        return
    assert reach.shape == (n,)
    assert np.allclose(reach, [max(np.linalg.norm(s[j] - P[j]) for s in samples) for j in range(n)], rtol=1e-12)
    assert np.array_equal([b[0][-1] for b in balls], reach)
    if d == 2:
        assert np.allclose(_disc_radii(P, reach_polygons(P, samples)), reach, rtol=1e-12)


@pytest.fixture(scope="module")
def op():
    shape = dop.shapes.load("bar")
    return dop.train(shape, basis="linear", m=6, seed=3, progress=False, n_jobs=1, rounds=1)[0]


def test_the_operator_the_editor_and_the_payload_agree(op):
    reach = training_reach(op.P, op.train_samples)
    assert reach is not None and np.all(reach > 0)
    assert np.array_equal(op._reach, reach)
    regions = defop_to_payload(op)["regions"]
    radii = _disc_radii(op.P, [[np.reshape(poly, (-1, 2))] for polys in regions for poly in polys[:1]])
    assert np.allclose(radii, reach, rtol=1e-12)
    assert np.allclose(_disc_radii(op.P, reach_polygons(op.P, op.train_samples)), reach, rtol=1e-12)


def test_the_extrapolation_warning_starts_at_the_reach(op):
    """Just inside 1.5 x the reach no warning, just outside one (the warning's threshold is the same reach)."""
    j = 0
    direction = np.zeros_like(op.P)
    direction[j, 1] = 1.0
    reach = training_reach(op.P, op.train_samples)[j]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)
        op(op.P + (EXTRAPOLATION_FACTOR * reach * (1 - 1e-6)) * direction)
    with pytest.warns(ExtrapolationWarning, match=f"{reach:.3g}"):
        op(op.P + (EXTRAPOLATION_FACTOR * reach * (1 + 1e-6)) * direction)
