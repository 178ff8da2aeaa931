"""Bootstrapped training (§3.3): stages, parallel solves (joblib, Dask), on-disk cache."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))


def test_train_stages_and_claims(bar):
    op, rec = dop.train.train(bar, "sarap", "tps", m=12, seed=1, n_jobs=1, progress=False)
    assert set(rec.stage_times) == {"bootstrap", "solve", "fit", "fold"} and rec.cache == "none"
    assert rec.converged.all() and rec.X.shape == (12, bar.mesh.n_vertices, 2)
    assert np.abs(op(rec.samples) - rec.X).max() < 1e-8  # Prop. 1 on the training set
    assert np.abs(op(bar.P_moving) - bar.mesh.V).max() < 1e-12
    assert op.meta["shape"] == "bar" and op.meta["energy"] == "sarap" and op.n_samples == 12
    # every ground-truth sample is a converged, flip-free S-ARAP solution
    assert all(not bar.mesh.flipped(X).any() for X in rec.X)


def test_cache_returns_the_same_operator_and_reuses_ground_truth(bar):
    a, ra = dop.train.train(bar, "sarap", "tps", m=10, seed=2, n_jobs=1, progress=False)
    b, rb = dop.train.train(bar, "sarap", "tps", m=10, seed=2, n_jobs=1, progress=False)
    assert rb.cache == "operator" and np.array_equal(a(ra.samples), b(rb.samples))
    c, rc = dop.train.train(bar, "sarap", "linear", m=10, seed=2, n_jobs=1, progress=False)
    assert rc.cache == "ground truth" and np.array_equal(rc.X, ra.X)
    d, rd = dop.train.train(bar, "sarap", "tps", m=10, seed=3, n_jobs=1, progress=False)
    assert rd.cache == "none"  # another seed, other samples


def test_parallel_solves_match_serial(bar):
    Q = dop.sampling.sample_shape(bar, 6, 5)
    Xs, cs = dop.train.solve_samples(bar, Q, "arap", n_jobs=1, progress=False)
    Xp, cp = dop.train.solve_samples(bar, Q, "arap", n_jobs=2, progress=False)
    assert cs.all() and cp.all() and np.allclose(Xs, Xp, atol=1e-12)


def test_dask_backend(bar):
    pytest.importorskip("dask.distributed")
    import joblib
    from dask.distributed import Client, LocalCluster

    Q = dop.sampling.sample_shape(bar, 4, 6)
    Xs, _ = dop.train.solve_samples(bar, Q, "arap", n_jobs=1, progress=False)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with Client(cluster), joblib.parallel_backend("dask"):
            Xd, cd = dop.train.solve_samples(bar, Q, "arap", n_jobs=-1, progress=False)
    assert cd.all() and np.allclose(Xs, Xd, atol=1e-12)
