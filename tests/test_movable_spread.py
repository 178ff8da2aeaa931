"""The joint training's spread design (:func:`defop.training.movable.spread_joint`): the m farthest apart of a pool."""

from __future__ import annotations

import numpy as np
import pytest

from defop.operator.movable import joint_points
from defop.scene.placement import placement_regions
from defop.training.movable import POOL, sample_joint, spread_joint, train_movable


@pytest.fixture(scope="module")
def shape(movable_rect):
    """The 2 x 1 rectangle of tests/conftest.py, about 160 vertices: two moving handles (movable), one fixed."""
    return movable_rect(160)


@pytest.fixture(scope="module")
def placement(shape):
    return placement_regions(shape, [0, 1], radius=0.15)


def _z(shape, placement, idx, Q, scales):
    """Joint coordinates of (idx, Q) with given scales, flattened (k, (b + n) d)."""
    z, _, off_q = joint_points(shape.mesh, placement, shape.moving, idx, Q)
    _, (s_p, s_q), _ = joint_points(shape.mesh, placement, shape.moving, *scales)
    off_p = shape.mesh.V[idx] - shape.mesh.V[placement.nominal]
    return np.concatenate([off_p / s_p, off_q / s_q], axis=1).reshape(len(idx), -1)


def _covering_radius(points, picked):
    """The largest distance from a point to its nearest picked point."""
    d2 = ((points[:, None, :] - picked[None, :, :]) ** 2).sum(-1)
    return float(np.sqrt(d2.min(axis=1).max()))


def test_spread_samples_are_pool_draws_covering_it_better_than_uniform(shape, placement):
    """The m picked samples are draws of the pool (same seed: the same pool), and they leave no pool draw as far
    from its nearest sample as the first m draws (the uniform design) do: the covering radius of the pool in Ψ's
    coordinates falls."""
    m = 40
    pidx, pQ = sample_joint(shape, placement, POOL * m, np.random.default_rng(3))
    idx, Q = spread_joint(shape, placement, m, np.random.default_rng(3))
    assert idx.shape == (m, 2) and Q.shape == (m, 2, 2)
    rows = [int(np.flatnonzero((pidx == i).all(1) & (pQ == q).all((1, 2)))[0]) for i, q in zip(idx, Q)]
    assert rows == sorted(set(rows))  # distinct draws of the pool, in the order drawn
    zp = _z(shape, placement, pidx, pQ, (pidx, pQ))
    spread = _covering_radius(zp, zp[rows])
    uniform = _covering_radius(zp, zp[:m])
    assert spread < 0.9 * uniform, (spread, uniform)  # 0.80 here (8 dimensions)


def test_spread_keeps_a_placements_samples_together_and_pool_one_is_uniform(shape, placement):
    idx, Q = spread_joint(shape, placement, 10, 7, n_q=3)
    assert idx.shape == (30, 2) and Q.shape == (30, 2, 2)
    assert all((idx[3 * k] == idx[3 * k + 1 :][:2]).all() for k in range(10))  # n_q rows per placement
    a = spread_joint(shape, placement, 12, 5, pool=1)
    b = sample_joint(shape, placement, 12, 5)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    again = spread_joint(shape, placement, 10, 7, n_q=3)
    assert np.array_equal(again[0], idx) and np.array_equal(again[1], Q)  # a seed: the same samples


def test_design_refused_before_any_solve(shape, placement):
    with pytest.raises(ValueError, match="unknown design 'grid'; known: spread, uniform"):
        train_movable(shape, placement, m=5, design="grid", n_jobs=1, progress=False, cache=False)
    with pytest.raises(ValueError, match="pool must be an integer >= 1"):
        spread_joint(shape, placement, 5, 0, pool=0)
