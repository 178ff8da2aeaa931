"""Long trainings show an ETA and resume after an interruption without re-solving finished samples (issue 28)."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.training import batch, bootstrap, solves


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(batch, "CHUNK", 3)  # small checkpoints, so a short training has several


_SOLVE = solves.solve_chunk  # the real one, wrapped afresh by each _counting


def _counting(monkeypatch, stop_after=None):
    """Count the samples solved (n_jobs=1: one call per sample); raise KeyboardInterrupt on solve stop_after + 1."""
    calls = []
    solve = _SOLVE

    def counted(problem, jobs):
        if stop_after is not None and len(calls) >= stop_after:
            raise KeyboardInterrupt
        calls.append(len(jobs))
        return solve(problem, jobs)

    monkeypatch.setattr(solves, "solve_chunk", counted)
    return calls


def _saved(folder):
    """Samples held by the chunk checkpoints in the cache folder."""
    return sum(len(np.load(p)["converged"]) for p in folder.glob("chunk-*.npz"))


# the bar's one moving handle: 3 bootstrap solves (one chunk or less: no checkpoint), 7 sample solves and 10
# re-solves in chunks of 3; interrupted at solve 8, 3 samples are kept, at solve 15, 7 + 3
@pytest.mark.parametrize("stop_after, kept", [(7, 3), (14, 10)])
def test_an_interrupted_training_resumes_without_re_solving(bar, tmp_path, monkeypatch, stop_after, kept):
    kw = dict(energy="sarap", basis="tps", m=10, seed=3, n_jobs=1, progress=False)
    calls = _counting(monkeypatch)
    ref, ref_rec = dop.train(bar, cache=False, **kw)
    total = sum(calls)
    _counting(monkeypatch, stop_after)
    with pytest.raises(KeyboardInterrupt):
        dop.train(bar, **kw)
    folder = tmp_path / "cache"
    saved = _saved(folder)
    assert saved == kept  # whole chunks (of 3 samples, or the end of a stage)
    calls = _counting(monkeypatch)
    op, rec = dop.train(bar, **kw)
    assert sum(calls) == total - saved  # only the samples not finished before the interruption
    assert rec.cache == "none" and rec.converged.all()
    assert np.array_equal(rec.X, ref_rec.X) and np.array_equal(op.W, ref.W)  # the same operator, bit for bit
    assert not list(folder.glob("chunk-*.npz"))  # checkpoints removed once the ground truth is cached


def test_checkpoints_do_not_depend_on_n_jobs(bar, tmp_path, monkeypatch):
    """Chunks are fixed (batch.CHUNK), so a run interrupted with one worker count resumes with another."""
    Q = dop.training.sampling.sample_shape(bar, 7, np.random.default_rng(4))
    store = dop.training.cache.open_cache()
    a = bootstrap.solve_samples(bar, Q, n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store))
    calls = _counting(monkeypatch)
    b = bootstrap.solve_samples(bar, Q, n_jobs=2, progress=False, checkpoint=batch.Checkpoints(store))
    assert sum(calls) == 0 and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_the_bar_shows_the_rate_and_the_eta(monkeypatch):
    monkeypatch.setenv("DEFOP_PROGRESS", "text")
    bar = batch.progress(40, "sample solves", True)
    try:
        bar.update(3)
        text = str(bar)
    finally:
        bar.close()
    assert "3/40" in text and "<" in text and "solve" in text  # [elapsed<remaining, rate solve/s]
