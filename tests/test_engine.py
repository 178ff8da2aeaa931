"""The sample engine (defop.training.solves): its policies agree with the solver, across worker counts."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

import defop as dop
from defop.training import multilevel as ml
from defop.training import paths, solves
from defop.training.sampling import sample_shape
from defop.variational.solver import NotConvergedWarning


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture(scope="module")
def Q(bar):
    return sample_shape(bar, 4, np.random.default_rng(11))


def test_sweep_is_the_path_of_local_solves(bar, Q):
    got = paths.sweep(bar, Q, "arap")
    solver, X, ref = dop.variational.Solver(bar.mesh, bar.handles, "arap"), None, []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for q in Q:
            r = solver.solve(bar.targets(q), X0=X)
            X = r.X
            ref.append((r.X, r.energy, r.converged))
    assert np.array_equal(got.X, np.array([r[0] for r in ref]))
    assert np.array_equal(got.energy, [r[1] for r in ref]) and np.array_equal(got.converged, [r[2] for r in ref])
    assert got.runs is None and got.cpu_seconds >= got.local_cpu_seconds >= 0.0


def test_every_end_point_kept_has_the_same_winner(bar, Q):
    """keep="all" (the coarse stage of the multilevel policy) and keep="best" (the full policy) pick the same
    minimum from the same starts, on any worker count."""
    starts = [[bar.mesh.V + 0.01], None, bar.mesh.V, None]
    best = solves.solve(bar, Q, "arap", starts=starts, n_jobs=1, progress=False)
    every = solves.solve(bar, Q, "arap", starts=starts, n_jobs=2, progress=False, keep="all")
    assert np.array_equal(best.X, every.X) and np.array_equal(best.converged, every.converged)
    assert [len(r) for r in every.runs] == [2, 1, 2, 1]
    for X, runs in zip(every.X, every.runs):
        assert any(np.array_equal(X, R) for R, _, _ in runs)


def test_incumbent_wins_ties_and_is_verified_not_resolved(bar, Q):
    first = solves.solve(bar, Q, "arap", n_jobs=1, progress=False)
    again = solves.solve(bar, Q, "arap", incumbents=list(first.X), rest=False, n_jobs=1, progress=False)
    assert np.array_equal(again.X, first.X) and again.converged.all()
    np.testing.assert_allclose(again.energy, first.energy, rtol=1e-12)


def test_stopwatch_counts_other_processes_once():
    clock = solves.Stopwatch()
    r = solves.Solves(np.zeros((1, 1, 2)), np.zeros(1), np.ones(1, bool), cpu_seconds=5.0, local_cpu_seconds=2.0)
    assert clock.add(r) is r and clock.remote == 3.0


def test_training_reports_cpu_and_wall_seconds_per_stage(bar):
    _, rec = dop.train(bar, "arap", "linear", m=6, seed=2, n_jobs=1, progress=False, cache=False)
    assert set(rec.stage_times) == set(rec.wall_times) == {"bootstrap", "solve", "fit", "fold"}


def test_the_bad_lengths_are_refused(bar, Q):
    with pytest.raises(ValueError, match="X0 must give one warm start"):
        solves.solve(bar, Q, starts=[None], n_jobs=1, progress=False)
    with pytest.raises(ValueError, match="keep"):
        solves.solve(bar, Q, keep="some", n_jobs=1, progress=False)


@pytest.mark.parametrize("old, new", [("Levels", "CoarseLevel"), ("levels", "coarse_level")])
def test_renamed_multilevel_names_warn(old, new):
    with pytest.warns(DeprecationWarning, match=f"{old} is renamed {new}"):
        assert getattr(ml, old) is getattr(ml, new)


def test_checkpointed_solves_count_their_cpu_seconds(bar, tmp_path):
    """A batch longer than a checkpoint chunk, solved now: every solve's CPU seconds reach the record (they were
    dropped for checkpointed chunks, so a cached training recorded a few CPU seconds for a thousand solves); loaded
    again, the same chunks cost nothing and give the same solutions."""
    import time

    from defop.training import batch
    from defop.training.cache import Cache

    Q = sample_shape(bar, batch.CHUNK + 3, np.random.default_rng(5))
    store = Cache(tmp_path)
    t0 = time.process_time()
    fresh = solves.solve(bar, Q, "arap", n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store))
    spent = time.process_time() - t0
    assert fresh.cpu_seconds == fresh.local_cpu_seconds > 0.5 * spent  # the solves are most of the call
    again = solves.solve(bar, Q, "arap", n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store))
    assert np.array_equal(again.X, fresh.X) and np.array_equal(again.converged, fresh.converged)
    assert again.cpu_seconds == 0.0


def test_the_run_keywords_are_named_and_a_misspelt_one_is_refused(bar, Q):
    """``solve``'s run settings (workers, progress, checkpoints, clock) travel as one :class:`solves.Run`; a
    misspelt keyword is a TypeError naming it, before any solve, never silently ignored."""
    with pytest.raises(TypeError, match="n_job"):
        solves.solve(bar, Q, "arap", n_job=1)
    clock = solves.Stopwatch()
    got = solves.solve(bar, Q, "arap", n_jobs=2, progress=False, clock=clock)
    assert clock.remote == got.cpu_seconds - got.local_cpu_seconds > 0.0  # the caller's clock counted the workers
    assert [f.name for f in dataclasses.fields(solves.Run)] == [
        "n_jobs",
        "progress",
        "desc",
        "checkpoint",
        "key_of",
        "clock",
    ]
