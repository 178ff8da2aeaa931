"""The movable joint solve refuses what ``train`` refuses, before any solve: one configuration of every moving handle
(no broadcast), as many placements as configurations (no truncation), whole vertex indices (no truncation)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from defop.scene.placement import placement_regions
from defop.training import solves
from defop.training.movable import sample_joint, shape_at, solve_joint, vertex_indices


@pytest.fixture(scope="module")
def shape(movable_rect):
    return movable_rect(150)  # tests/conftest.py


@pytest.fixture(scope="module")
def placement(shape):
    return placement_regions(shape, [0, 1], radius=0.15)


@pytest.fixture
def no_solves(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("a solve ran before the inputs were checked")

    monkeypatch.setattr(solves, "solve_chunk", fail)


def _joint(shape, placement, m=3):
    return sample_joint(shape, placement, m, np.random.default_rng(5))


def test_one_target_for_two_moving_handles_is_refused(shape, placement, no_solves):
    idx, Q = _joint(shape, placement)
    with pytest.raises(ValueError, match=r"Q must have shape \(m, 2, 2\).*\(3, 1, 2\)"):
        solve_joint(shape, placement, idx, Q[:, :1], n_jobs=1, progress=False, cache=False)


def test_placements_and_configurations_of_different_lengths_are_refused(shape, placement, no_solves):
    idx, Q = _joint(shape, placement)
    with pytest.raises(ValueError, match=r"idx and Q .* 2 placements, 3 Q"):
        solve_joint(shape, placement, idx[:2], Q, n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match=r"idx and Q .* 3 placements, 2 Q"):
        solve_joint(shape, placement, idx, Q[:2], n_jobs=1, progress=False, cache=False)


def test_fractional_vertices_are_refused(shape, placement, no_solves):
    idx, Q = _joint(shape, placement)
    frac = idx.astype(float)
    frac[1, 0] += 0.5
    with pytest.raises(ValueError, match=r"idx must hold integer vertex indices.*not a whole number"):
        solve_joint(shape, placement, frac, Q, n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match=r"idx must hold integer vertex indices.*not a whole number"):
        shape_at(shape, placement, frac[1])
    with pytest.raises(ValueError, match=r"idx must have shape \(2\)"):
        shape_at(shape, placement, idx[:, 0])


def test_sample_joint_blames_n_q(shape, placement):
    with pytest.raises(ValueError, match=r"n_q must be an integer >= 1, got 0"):
        sample_joint(shape, placement, 3, 0, n_q=0)


def test_integral_float_vertices_are_the_same_placement(shape, placement):
    idx, _ = _joint(shape, placement)
    a, b = shape_at(shape, placement, idx[0]), shape_at(shape, placement, idx[0].astype(float))
    assert np.array_equal(a.handles, b.handles) and a.name == b.name


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 10_000), min_size=2, max_size=2), st.floats(0.001, 0.999))
def test_vertex_indices_never_truncate(whole, frac):
    assert vertex_indices("idx", np.array(whole, float), (2,)).tolist() == whole
    bad = np.array(whole, float)
    bad[-1] += frac
    with pytest.raises(ValueError, match="not a whole number"):
        vertex_indices("idx", bad, (2,))
