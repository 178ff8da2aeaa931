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
    op, rec = dop.train(bar, "sarap", "tps", m=12, seed=1, n_jobs=1, progress=False)
    assert set(rec.stage_times) == {"bootstrap", "solve", "fit", "fold"} and rec.cache == "none"
    assert rec.converged.all() and rec.X.shape == (12, bar.mesh.n_vertices, 2)
    assert np.abs(op(rec.samples) - rec.X).max() < 1e-8  # Prop. 1 on the training set
    assert np.abs(op(bar.P_moving) - bar.mesh.V).max() < 1e-12
    assert op.meta["shape"] == "bar" and op.meta["energy"] == "sarap" and op.n_samples == 12
    # every ground-truth sample is a converged, flip-free S-ARAP solution
    assert all(not bar.mesh.flipped(X).any() for X in rec.X)


def test_cache_returns_the_same_operator_and_reuses_ground_truth(bar):
    a, ra = dop.train(bar, "sarap", "tps", m=10, seed=2, n_jobs=1, progress=False)
    b, rb = dop.train(bar, "sarap", "tps", m=10, seed=2, n_jobs=1, progress=False)
    assert rb.cache == "operator" and np.array_equal(a(ra.samples), b(rb.samples))
    c, rc = dop.train(bar, "sarap", "linear", m=10, seed=2, n_jobs=1, progress=False)
    assert rc.cache == "ground truth" and np.array_equal(rc.X, ra.X)
    d, rd = dop.train(bar, "sarap", "tps", m=10, seed=3, n_jobs=1, progress=False)
    assert rd.cache == "none"  # another seed, other samples


def test_parallel_solves_match_serial(bar):
    Q = dop.training.sampling.sample_shape(bar, 6, 5)
    Xs, cs = dop.training.solve_samples(bar, Q, "arap", n_jobs=1, progress=False)
    Xp, cp = dop.training.solve_samples(bar, Q, "arap", n_jobs=2, progress=False)
    assert cs.all() and cp.all() and np.allclose(Xs, Xp, atol=1e-12)


def test_dask_backend(bar):
    pytest.importorskip("dask.distributed")
    import joblib
    from dask.distributed import Client, LocalCluster

    Q = dop.training.sampling.sample_shape(bar, 4, 6)
    Xs, _ = dop.training.solve_samples(bar, Q, "arap", n_jobs=1, progress=False)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with Client(cluster), joblib.parallel_backend("dask"):
            Xd, cd = dop.training.solve_samples(bar, Q, "arap", n_jobs=-1, progress=False)
    assert cd.all() and np.allclose(Xs, Xd, atol=1e-12)


# ------------------------------------------------------------------------------ option validation
@pytest.fixture
def no_solves(monkeypatch):
    """Every check below must fire before the first solve."""

    def fail(*a, **k):
        raise AssertionError("a solve ran before the options were checked")

    monkeypatch.setattr(dop.variational.Solver, "solve", fail)  # the primitive every driver calls


@pytest.mark.parametrize("basis", ["linear", "quadratic", "cubic", "tps"])
def test_too_few_samples_names_the_basis_and_its_minimum(bar, basis, no_solves):
    need = dop.training.min_samples(basis, bar.n_moving)
    with pytest.raises(ValueError) as exc:
        dop.train(bar, "sarap", basis, m=need - 1, n_jobs=1, progress=False)
    msg = str(exc.value)
    assert f"the {basis} handle basis needs at least {need} samples" in msg and f"m = {need - 1}" in msg
    assert basis == "linear" or "linear" not in msg
    with pytest.raises(ValueError, match=f"the {basis} handle basis needs at least {need} samples"):
        dop.train(bar, "sarap", basis, samples=np.tile(bar.P_moving, (need - 1, 1, 1)) + 0.1, progress=False)


def test_tps_with_one_sample_complains_about_tps(bar, no_solves):
    with pytest.raises(ValueError, match=r"the tps handle basis needs at least 3 samples .* got m = 1") as exc:
        dop.train(bar, basis="tps", m=1, n_jobs=1, progress=False)
    assert "linear" not in str(exc.value)


@pytest.mark.parametrize("basis", ["linear", "quadratic", "cubic", "tps"])
def test_the_minimum_number_of_samples_trains(bar, basis):
    """The minimum is exact: that many samples train, and the operator reproduces them (Prop. 1/2)."""
    need = dop.training.min_samples(basis, bar.n_moving)
    op, rec = dop.train(bar, "arap", basis, m=need, seed=3, n_jobs=1, progress=False, cache=False)
    assert op.meta["basis"] == basis and rec.X.shape[0] == need
    assert np.abs(op(bar.P_moving) - bar.mesh.V).max() < 1e-10  # rest pose exact, (8b)


BAD_TRAIN_OPTIONS = [
    ({"m": 0}, "m must be an integer >= 1, got 0"),
    ({"m": -5}, "m must be an integer >= 1, got -5"),
    ({"m": 12.5}, "m must be an integer >= 1, got 12.5"),
    ({"m": True}, "m must be an integer >= 1, got True"),
    ({"m": "12"}, "m must be an integer >= 1, got '12'"),
    ({"m": float("nan")}, "m must be an integer >= 1, got nan"),
    ({"seed": -1}, "seed must be an integer >= 0, got -1"),
    ({"seed": 1.5}, "seed must be an integer >= 0, got 1.5"),
    ({"seed": None}, "seed must be an integer >= 0, got None"),
    ({"n_jobs": 0}, "n_jobs must be a non-zero integer"),
    ({"n_jobs": 1.5}, "n_jobs must be an integer, got 1.5"),
    ({"energy": "elastic"}, "unknown energy 'elastic'; known energies: arap, sarap, isometric"),
    ({"basis": "rbf"}, "unknown handle basis 'rbf'; known: linear, quadratic, cubic, tps"),
    ({"basis": None}, "unknown handle basis None"),
    ({"spatial": "fourier"}, "unknown spatial basis 'fourier'; known: hat, reduced"),
    ({"spatial": "reduced", "k": 0}, "k must be an integer >= 3 and <= 198, got 0"),
    ({"spatial": "reduced", "k": 2.5}, "k must be an integer >= 3 and <= 198, got 2.5"),
    ({"spatial": "reduced", "k": 199}, "k must be an integer >= 3 and <= 198, got 199"),
    ({"rounds": 0}, "rounds must be an integer >= 1, got 0"),
    ({"rounds": 1.5}, "rounds must be an integer >= 1, got 1.5"),
    ({"samples": np.zeros((4, 2, 2))}, r"samples must have shape \(m, 1, 2\), m >= 1, for 1 moving handles"),
    ({"samples": np.zeros((0, 1, 2))}, r"samples must have shape \(m, 1, 2\), m >= 1"),
    ({"samples": np.full((4, 1, 2), np.nan)}, "samples has NaN or infinite entries"),
]


@pytest.mark.parametrize(("options", "message"), BAD_TRAIN_OPTIONS, ids=[str(o) for o, _ in BAD_TRAIN_OPTIONS])
def test_train_rejects_bad_options_by_name(bar, options, message, no_solves):
    kw = dict(energy="sarap", basis="tps", m=12, n_jobs=1, progress=False) | options
    with pytest.raises(ValueError, match=message):
        dop.train(bar, **kw)


def test_a_bad_defop_n_jobs_is_named_before_any_work(bar, monkeypatch, no_solves):
    for value in ("many", "0", "1.5"):
        monkeypatch.setenv("DEFOP_N_JOBS", value)
        with pytest.raises(ValueError, match=f"DEFOP_N_JOBS must be a non-zero integer .*, got '{value}'"):
            dop.train(bar, m=12, progress=False)


BAD_HELD_OUT = [
    ({"m": 0}, "m must be an integer >= 1, got 0"),
    ({"m": 2.5}, "m must be an integer >= 1, got 2.5"),
    ({"seed": -3}, "seed must be an integer >= 0, got -3"),
    ({"n_jobs": 0}, "n_jobs must be a non-zero integer"),
    ({"energy": "neo-hookean"}, "unknown energy 'neo-hookean'"),
    ({"like": 5}, "like must be a trained operator"),
]


@pytest.mark.parametrize(("options", "message"), BAD_HELD_OUT, ids=[str(o) for o, _ in BAD_HELD_OUT])
def test_held_out_rejects_bad_options_by_name(bar, options, message, no_solves):
    kw = dict(energy="sarap", m=4, seed=9, n_jobs=1, progress=False) | options
    with pytest.raises(ValueError, match=message):
        dop.training.held_out(bar, **kw)


@pytest.mark.parametrize("function", ["solve_samples", "sample_ground_truth"])
def test_sample_solvers_reject_bad_options_by_name(bar, function, no_solves):
    solve = getattr(dop.training.bootstrap, function)
    Q = np.tile(bar.P_moving, (3, 1, 1)) + 0.05
    with pytest.raises(ValueError, match="unknown energy 'ARAP'"):
        solve(bar, Q, "ARAP", progress=False)
    with pytest.raises(ValueError, match=r"samples must have shape \(m, 1, 2\)"):
        solve(bar, Q[:, :, :1], "arap", progress=False)
    with pytest.raises(ValueError, match="samples has NaN"):
        solve(bar, Q * np.nan, "arap", progress=False)
    with pytest.raises(ValueError, match="n_jobs must be a non-zero integer"):
        solve(bar, Q, "arap", n_jobs=0, progress=False)
    with pytest.raises(ValueError, match="X0 must give one warm start .* 2 for 3 samples"):
        solve(bar, Q, "arap", X0=[None, None], n_jobs=1, progress=False)


def test_the_largest_reduced_basis_allowed_trains(bar):
    k = bar.mesh.n_vertices - 4  # the bound train checks before any solve
    op, _ = dop.train(bar, "arap", "linear", m=2, spatial="reduced", k=k, n_jobs=1, progress=False, cache=False)
    assert op.meta["spatial"] == "reduced" and op.meta["spatial_size"] == k


def test_equal_given_samples_are_refused_before_any_solve(monkeypatch):
    """Two equal Q_k for the tps basis (equal centres) failed only in the fit, after every sample was solved."""
    bar = dop.shapes.load("bar")
    samples = bar.P_moving + 0.05 * np.random.default_rng(0).normal(size=(6, bar.n_moving, 2))
    samples[4] = samples[1]

    def no_solve(*args, **kw):
        raise AssertionError("solved before checking the samples")

    monkeypatch.setattr(dop.training.bootstrap, "solve_samples", no_solve)
    with pytest.raises(ValueError, match="samples 1 and 4 are the same handle configuration"):
        dop.train(bar, "sarap", "tps", samples=samples, progress=False)


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("n", [1, 2, 4])
def test_min_samples_reads_the_dimension(n, d):
    # |Ψ| - 1 for the polynomial bases (the rest pose is added by the fit); dn + 1 for TPS (|Ψ| = 1 + dn + m, side
    # conditions 1 + dn: the fit needs dn + 2 configurations with the rest pose)
    assert dop.training.min_samples("linear", n, d) == d * n
    assert dop.training.min_samples("quadratic", n, d) == (d * n + 2) * (d * n + 1) // 2 - 1
    assert dop.training.min_samples("tps", n, d) == d * n + 1
    if d == 2:
        assert dop.training.min_samples("quadratic", n) == 3 * n + 2 * n * n  # the 2D default, as before
