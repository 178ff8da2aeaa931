"""Adaptive sampling (issue 28): the pure selection functions, verified samples, determinism for any n_jobs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import defop as dop
from defop.training import adaptive as ad


@pytest.fixture(scope="module")
def aleph():
    return dop.shapes.load("aleph", n_vertices=300)


@given(st.integers(0, 2**31 - 1), st.integers(1, 6))
def test_select_batch_takes_distinct_high_scores_in_a_fixed_order(seed, size):
    rng = np.random.default_rng(seed)
    candidates, samples = rng.normal(size=(30, 2, 2)), rng.normal(size=(5, 2, 2))
    scores = rng.random(30)
    chosen = ad.select_batch(scores, candidates, samples, size)
    assert len(chosen) == size == len(set(chosen.tolist()))
    assert np.array_equal(chosen, ad.select_batch(scores.copy(), candidates.copy(), samples.copy(), size))
    # the first pick maximises score x damping by the distance to the samples: never a candidate already sampled
    candidates[chosen[0]] = samples[0]
    assert chosen[0] not in ad.select_batch(scores, candidates, samples, 1)


def test_select_batch_refuses_bad_arguments_and_spreads_out_when_nothing_is_uncertain():
    rng = np.random.default_rng(0)
    candidates, samples, scores = rng.normal(size=(6, 2, 2)), rng.normal(size=(3, 2, 2)), rng.random(6)
    for args, name in (
        ((scores, candidates, samples, 7), "size"),
        ((scores, candidates, samples, 0), "size"),
        ((scores[:5], candidates, samples, 2), "scores"),
        ((np.where(np.arange(6) == 2, np.nan, scores), candidates, samples, 2), "scores"),
        ((-scores, candidates, samples, 2), "scores"),
        ((scores, candidates, samples[:0], 2), "samples"),
        ((scores, candidates, samples[:, :1], 2), "samples"),
    ):
        with pytest.raises(ValueError, match=name):
            ad.select_batch(*args)
    candidates[:3] = samples  # three candidates are already sampled, and no score says anything
    chosen = ad.select_batch(np.zeros(6), candidates, samples, 3)
    assert sorted(chosen.tolist()) == [3, 4, 5]


def test_disagreement_is_the_8a_term_of_the_difference():
    mass = np.array([1.0, 2.0, 3.0])

    def a(Q):
        return np.repeat(Q.reshape(len(Q), 1, -1)[..., :2], 3, axis=1)

    def b(Q):
        return 2 * a(Q)

    Q = np.arange(8.0).reshape(2, 2, 2)
    expect = [6 * (0**2 + 1**2), 6 * (4**2 + 5**2)]
    assert np.allclose(ad.disagreement(a, b, Q, mass), expect) and not ad.disagreement(a, a, Q, mass).any()


def test_energy_residual_is_zero_at_rest_and_small_at_training_samples(aleph):
    op, rec = dop.train(aleph, "sarap", "tps", m=12, seed=0, n_jobs=1, cache=False, progress=False)
    far = dop.training.sampling.sample_shape(aleph, 12, np.random.default_rng(9))
    r_rest = ad.energy_residual(aleph, op, aleph.P_moving[None])
    r_train, r_far = ad.energy_residual(aleph, op, rec.samples), ad.energy_residual(aleph, op, far)
    assert r_rest[0] < 1e-20 and np.median(r_train) < 1e-3 * np.median(r_far)  # Prop. 1: D interpolates minima


@pytest.mark.parametrize("criterion", ["residual", "disagreement"])
def test_adaptive_training_is_deterministic_and_verified(aleph, criterion):
    kw = dict(m=30, seed=4, batch=4, pool=60, criterion=criterion, cache=False, progress=False)
    a, ra = dop.training.train_adaptive(aleph, n_jobs=1, **kw)
    b, rb = dop.training.train_adaptive(aleph, n_jobs=2, **kw)
    assert ra.converged.all() and rb.converged.all()  # every sample a verified minimum
    assert ra.params["counts"] == [22, 26, 30] and len(ra.samples) == 30
    assert np.array_equal(ra.samples, rb.samples)  # the same samples chosen
    assert np.abs(a.W - b.W).max() <= 1e-9 * aleph.mesh.bbox_diagonal * np.abs(a.W).max()
    assert np.abs(a(rb.samples) - b(rb.samples)).max() <= 1e-9 * aleph.mesh.bbox_diagonal
    assert np.abs(a(ra.samples) - ra.X).max() < 1e-8  # Prop. 1 on the chosen samples
    pool = dop.training.sampling.sample_shape(aleph, 60, np.random.default_rng([4, 1]))
    assert all((np.abs(pool - q).max(axis=(1, 2)) == 0).any() for q in ra.samples[22:])  # drawn from the pool


@pytest.mark.parametrize(
    "bad, word",
    [
        (dict(criterion="entropy"), "criterion"),
        (dict(batch=0), "batch"),
        (dict(m=10), "m"),
        (dict(pool=3), "pool"),
        (dict(n_initial=5), "n_initial"),
    ],
)
def test_bad_options_raise_before_any_solve(aleph, bad, word, monkeypatch):
    monkeypatch.setattr(dop.training.bootstrap, "solve_samples", None)  # any solve would fail otherwise
    kw = dict(m=30, cache=False, progress=False) | bad
    with pytest.raises(ValueError, match=word):
        dop.training.train_adaptive(aleph, **kw)
