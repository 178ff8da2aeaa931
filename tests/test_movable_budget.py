"""The joint training's budget in solves, its solves' CPU seconds kept with the cached truth, and nested refits of
one joint training (the lesson 16_moving_handles compares error against CPU seconds with them)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import defop as dop
from defop.lessons.figure_data import joint_subset_fits
from defop.scene.placement import placement_regions
from defop.training.movable import budget_samples, train_movable, training_solves
from defop.training.record import TrainingRecord


def _record(m, rounds, policy):
    return TrainingRecord(np.zeros((m, 1, 2)), None, None, {}, "none", {"rounds": rounds}, policy)


@pytest.mark.parametrize(
    "m, rounds, policy, solves",
    [(200, 2, "full", 400), (200, 2, "multilevel", 600), (150, 1, "full", 150), (150, 1, "multilevel", 300)],
)
def test_budget_counts_the_records_solves(m, rounds, policy, solves):
    rec = _record(m, rounds, policy)
    assert training_solves(rec) == solves
    assert budget_samples(rec) == 5 * m  # a joint sample costs about what a fixed-P sample's solves cost
    assert budget_samples(rec, factor=2) == 2 * m


@pytest.mark.parametrize("factor", [0, -1, 2.5, "5"])
def test_budget_refuses_a_bad_factor(factor):
    with pytest.raises(ValueError, match="factor"):
        budget_samples(_record(200, 2, "full"), factor=factor)


def test_budget_of_a_real_training(tmp_path, monkeypatch):
    """The record of dop.train holds what the count reads: its samples, rounds and the policy that ran."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape = dop.shapes.load("bar")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, rec = dop.train(shape, m=12, n_jobs=1, progress=False)
    assert rec.policy == "multilevel" and rec.params["rounds"] == 2
    assert budget_samples(rec) == 5 * 12 and training_solves(rec) == 12 * 3


def test_nested_refits_and_solve_seconds_kept_in_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape = dop.shapes.load("bar")
    placement = placement_regions(shape, radius=0.05 * shape.mesh.bbox_diagonal)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, rec = train_movable(shape, placement, m=16, seed=3, n_jobs=1, progress=False)
        again, rec2 = train_movable(shape, placement, m=16, seed=3, n_jobs=1, progress=False)
    assert rec.solve_cpu_seconds > 0 and rec.fit_cpu_seconds > 0
    assert rec2.solve_cpu_seconds == rec.solve_cpu_seconds  # loaded with the truth, not the load's seconds
    fits = joint_subset_fits(shape, placement, rec, [4, 16])
    assert np.array_equal(fits[16][0].W, op.W)  # all the samples: the training's own fit, bit for bit
    assert fits[4][0].meta["n_samples"] == 4 and fits[4][1] >= 0
    for bad in ([1], [17], [2.5]):
        with pytest.raises(ValueError, match="sample counts"):
            joint_subset_fits(shape, placement, rec, bad)
