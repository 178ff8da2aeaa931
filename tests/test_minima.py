"""The one ``distinct_minima`` (defop.training.minima): the multilevel policy's and branch grouping's rules.

Hypothesis draws candidate sets (configurations, energies with ties, verified flags); the shared function keeps the
verified candidates, lowest energy first, each farther than tol × diagonal from those kept before, under either
distance, and with ``metric="max"`` returns what the multilevel policy's own loop returned.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.training import multilevel
from defop.training.minima import distinct_minima, rms


def multilevel_reference(candidates, diagonal, tol):
    """The multilevel policy's rule as it was written: sorted by energy, then filtered."""
    out = []
    for X, E, ok in sorted(candidates, key=lambda c: c[1]):
        if ok and all(np.abs(X - Y).max() > tol * diagonal for Y, _ in out):
            out.append((X, E))
    return out


candidate_sets = st.integers(0, 2**32 - 1).flatmap(
    lambda seed: st.tuples(st.just(seed), st.integers(0, 7), st.sampled_from([1e-3, 0.05, 0.3]))
)


@settings(max_examples=60, deadline=None)
@given(candidate_sets)
def test_max_metric_matches_the_multilevel_rule(case):
    seed, c, tol = case
    rng = np.random.default_rng(seed)
    X = rng.normal(scale=0.1, size=(c, 5, 2))
    X[rng.random(c) < 0.3] = X[0] if c else 0.0  # duplicates
    E = np.round(rng.normal(size=c), 1)  # ties
    ok = rng.random(c) < 0.7
    candidates = [(X[i], float(E[i]), bool(ok[i])) for i in range(c)]
    want = multilevel_reference(candidates, 1.0, tol)
    got = distinct_minima(X, E, ok, tol, 1.0, metric="max")
    assert [(x.tolist(), e) for x, e in want] == [(X[i].tolist(), float(E[i])) for i in got]
    if tol == multilevel.DISTINCT:
        assert [e for _, e in multilevel.distinct_minima(candidates, 1.0)] == [e for _, e in want]


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 6))
def test_rms_metric_keeps_verified_sorted_distinct_minima(seed, c):
    mesh = dop.shapes.load("bar", 200).mesh
    rng = np.random.default_rng(seed)
    X = mesh.V + rng.normal(scale=0.01, size=(c, *mesh.V.shape))
    E, ok = rng.normal(size=c), rng.random(c) < 0.8
    kept = distinct_minima(X, E, ok, 1e-3, mesh.bbox_diagonal, metric="rms", mesh=mesh)
    assert all(ok[kept]) and list(E[kept]) == sorted(E[kept])
    for a in range(len(kept)):
        for b in range(a):
            assert rms(mesh, X[kept[a]] - X[kept[b]]) > 1e-3 * mesh.bbox_diagonal
    if ok.any():
        assert kept[0] == np.flatnonzero(ok)[np.argmin(E[ok])]  # the lowest verified one is always kept


def test_bad_metric_is_refused_by_name():
    with pytest.raises(ValueError, match="metric must be one of"):
        distinct_minima(np.zeros((1, 2, 2)), [0.0], [True], 1e-3, 1.0, metric="l2")
    with pytest.raises(ValueError, match="needs the mesh"):
        distinct_minima(np.zeros((1, 2, 2)), [0.0], [True], 1e-3, 1.0, metric="rms")
