"""Handle samples Q_k: every region kind, seeded, fixed handles untouched."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.sampling import sample_handles

P = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


@pytest.mark.parametrize(
    "region, check",
    [
        (
            {"kind": "disc", "radius": 0.3},
            lambda d, q: np.all(d <= 0.3) and np.mean(d < 0.3 / np.sqrt(2)) == pytest.approx(0.5, abs=0.05),
        ),
        ({"kind": "circle", "radius": 0.2}, lambda d, q: np.allclose(d, 0.2)),
        ({"kind": "gaussian", "sigma": 0.1}, lambda d, q: np.std(q[:, 0]) == pytest.approx(0.1, rel=0.1)),
        ({"kind": "voronoi", "radius": 2.0}, lambda d, q: np.all(np.linalg.norm(q - P[1], axis=1) >= d)),
    ],
)
def test_region_kinds(region, check):
    Q = sample_handles(P, [region] * 3, 2000, np.random.default_rng(0))
    assert Q.shape == (2000, 3, 2)
    d = np.linalg.norm(Q[:, 0] - P[0], axis=1)
    assert check(d, Q[:, 0] - P[0])


def test_voronoi_stays_in_the_cell_and_mixture_mixes():
    mix = {
        "kind": "mixture",
        "components": [{"kind": "circle", "radius": 0.1}, {"kind": "voronoi", "radius": 0.8}],
        "weights": [1, 3],
    }
    Q = sample_handles(P, [mix] * 3, 4000, np.random.default_rng(1))
    d = np.linalg.norm(Q[:, 0] - P[0], axis=1)
    on_circle = np.isclose(d, 0.1)
    assert on_circle.mean() == pytest.approx(0.25, abs=0.03)
    q = Q[~on_circle, 0]
    assert np.all(np.linalg.norm(q - P[0], axis=1) <= np.linalg.norm(q[:, None] - P[1:], axis=-1).min(axis=1))


def test_seeded_and_reproducible():
    s = dop.shapes.load("octopus", n_vertices=600)
    a = dop.sampling.sample_shape(s, 50, 7)
    b = dop.sampling.sample_shape(s, 50, np.random.default_rng(7))
    assert np.array_equal(a, b) and a.shape == (50, s.n_moving, 2)
    assert not np.array_equal(a, dop.sampling.sample_shape(s, 50, 8))


def test_bad_input():
    with pytest.raises(ValueError, match="2 regions for 3 moving handles"):
        sample_handles(P, [{"kind": "disc", "radius": 1}] * 2, 5, 0)
    with pytest.raises(ValueError, match="needs a positive 'radius'"):
        sample_handles(P, [{"kind": "disc", "radius": -1}] * 3, 5, 0)
    with pytest.raises(ValueError, match="m must be a positive integer"):
        sample_handles(P, [{"kind": "disc", "radius": 1}] * 3, 0, 0)
