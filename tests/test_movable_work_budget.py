"""The joint training's budget counted in work (issue 44 item 3): where the count stops, that it is the same
whatever the clock says and however many workers solve, and what it refuses."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.scene.placement import placement_regions
from defop.training import work
from defop.training.movable_budget import budget_work, stop_at, train_within
from defop.training.record import TrainingRecord


def _record(spent, m=200):
    return TrainingRecord(np.zeros((m, 1, 2)), None, None, {}, "none", {"rounds": 2}, "multilevel", work=spent)


def test_stop_at_counts_each_placements_setup_once():
    work_, setup = np.array([1.0, 1.0, 1.0, 1.0]), np.array([10.0, 10.0, 5.0, 10.0])
    idx = np.array([[3], [3], [4], [3]])
    assert list(work.prefix(work_, setup, np.array([True, False, True, False]))) == [11, 12, 18, 19]
    assert stop_at(work_, setup, idx, 12.0) == (2, 12.0)  # the first sample whose prefix reaches the target
    assert stop_at(work_, setup, idx, 12.5) == (3, 18.0)
    assert stop_at(work_, setup, idx, 19.5) == (None, 19.0)  # never: the caller solves another chunk


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0, 1e6), st.floats(0, 1e7), st.integers(0, 5)), min_size=1, max_size=40),
    st.floats(1.0, 4e7),
    st.floats(1.0, 3.0),
)
def test_stop_at_is_the_first_sample_to_reach_the_target_and_monotone(rows, target, more):
    w, s, p = (np.array(c) for c in zip(*rows))
    idx = p[:, None]
    m, spent = stop_at(w, s, idx, target)
    first = np.zeros(len(p), bool)
    first[np.unique(p, return_index=True)[1]] = True
    total = np.cumsum(w + np.where(first, s, 0.0))
    if m is None:
        assert total[-1] < target
    else:
        assert total[m - 1] >= target and spent == total[m - 1]
        assert m == 1 or total[m - 2] < target
        m2, _ = stop_at(w, s, idx, target * more)  # a larger budget never stops earlier
        assert m2 is None or m2 >= m


@pytest.mark.parametrize("factor", [0, -1, float("nan"), float("inf"), "5", True])
def test_budget_refuses_a_bad_factor(factor):
    with pytest.raises(ValueError, match="factor must be a positive number"):
        budget_work(_record(1e6), factor)


@pytest.mark.parametrize("spent", [float("nan"), 0.0, -3.0, None])
def test_budget_refuses_a_record_without_work(spent):
    with pytest.raises(ValueError, match="holds no work"):
        budget_work(_record(spent), 5)
    assert budget_work(_record(2.0e6), 5) == 1.0e7 and budget_work(_record(2.0e6), 2.5) == 5.0e6


def test_stop_at_refuses_samples_without_work():
    with pytest.raises(ValueError, match="no work"):
        stop_at(np.array([1.0, np.nan]), np.zeros(2), np.zeros((2, 1), int), 1.0)


@pytest.fixture(scope="module")
def bar():
    shape = dop.shapes.load("bar")
    placement = placement_regions(shape, radius=0.05 * shape.mesh.bbox_diagonal)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, ref = dop.train(shape, m=12, n_jobs=1, progress=False, cache=False)
    return shape, placement, ref


def _within(bar, **kw):
    shape, placement, ref = bar
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return train_within(shape, placement, ref, **{"n_jobs": 1, "progress": False, "cache": False, **kw})


def test_training_work_is_kept_with_the_truth_and_independent_of_time(bar, tmp_path, monkeypatch):
    shape, _, ref = bar
    assert np.isfinite(ref.work) and ref.work > 0
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    clock = iter(np.random.default_rng(0).uniform(0, 1e6, 10**6))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with monkeypatch.context() as mp:
            mp.setattr(time, "process_time", lambda: float(next(clock)))  # any clock: the same work
            _, rec = dop.train(shape, m=12, n_jobs=1, progress=False)
        _, loaded = dop.train(shape, m=12, n_jobs=1, progress=False)
    assert rec.work == ref.work and rec.cache == "none"
    assert loaded.cache == "operator" and loaded.work == ref.work  # read back from the cached ground truth


def test_train_within_stops_where_the_work_reaches_the_budget(bar):
    shape, placement, ref = bar
    op, rec = _within(bar, factor=1.5)
    target = 1.5 * ref.work
    assert rec.budget["target"] == target and not rec.budget["capped"]
    m = len(rec.idx)
    assert rec.work + rec.budget["fit"] >= target and m <= rec.budget["solved"] and rec.budget["solved"] % 25 == 0
    assert rec.work_units == work.units(shape.mesh) == ref.work_units
    again, rec2 = _within(bar, factor=1.5)  # the same m and the same operator, twice
    assert len(rec2.idx) == m and rec2.work == rec.work
    q = shape.P_moving + 0.01
    assert np.array_equal(op(q, P=rec.idx[0]), again(q, P=rec.idx[0]))
    _, more = _within(bar, factor=3.0)  # a larger budget: a longer prefix of the same seeded sequence
    assert len(more.idx) > m
    assert np.array_equal(more.idx[:m], rec.idx) and np.array_equal(more.Q[:m], rec.Q)


def test_train_within_is_the_same_on_two_workers(bar):
    _, one = _within(bar, factor=1.0)
    _, two = _within(bar, factor=1.0, n_jobs=2)
    assert len(two.idx) == len(one.idx) and two.work == one.work


def test_train_within_refuses_a_record_without_work_before_any_solve(bar):
    shape, placement, _ = bar
    with pytest.raises(ValueError, match="holds no work"):
        train_within(shape, placement, _record(float("nan"), 12), progress=False, cache=False)


def test_fit_work_grows_with_the_samples_and_the_mesh():
    from defop.training.movable_budget import fit_work

    w = fit_work([1, 10, 100, 1000], 596, 2)
    assert np.all(np.diff(w) > 0) and np.all(fit_work(100, 2810, 2) > fit_work(100, 596, 2))


def test_reference_trains_again_where_the_cache_kept_no_work(monkeypatch):
    from defop.training import movable_budget as mb

    calls = []

    def fake(shape, m, seed, **kw):
        calls.append(kw.get("cache", True))
        return None, _record(float("nan") if len(calls) == 1 else 7.0, m)

    monkeypatch.setattr(mb, "train", fake)
    _, rec = mb.reference("shape", m=200, progress=False)
    assert calls == [True, False] and rec.work == 7.0


def test_stop_at_names_the_cause_of_a_missing_work():
    with pytest.raises(ValueError, match="did not run in this count.*counted=True"):
        stop_at(np.array([1.0, np.nan]), np.zeros(2), np.zeros((2, 1), int), 1.0)


def test_work_in_other_units_is_not_read_back_nor_compared(bar, tmp_path, monkeypatch):
    shape, placement, ref = bar
    units = work.units(shape.mesh)
    assert set(units) == {"backend", "reuse", "iteration", "hessian", "setup", "solver", "draw", "version"}
    assert ref.work_units == units
    assert work.recorded({"work": 5.0, "work_units": units}, shape.mesh) == 5.0
    assert np.isnan(work.recorded({"work": 5.0}, shape.mesh))  # cached before the units were kept
    assert np.isnan(work.recorded({"work": 5.0, "work_units": {**units, "backend": "pardiso"}}, shape.mesh))
    other = {**units, "reuse": not units["reuse"]}
    with pytest.raises(ValueError, match="other units.*against"):
        budget_work(_record(2.0e6), 5, units)  # a record without units
    rec = _record(2.0e6, 12)
    rec.work_units = other
    with pytest.raises(ValueError, match=f"other units.*'reuse': {other['reuse']}.*'reuse': {units['reuse']}"):
        budget_work(rec, 5, units)  # both named
    assert budget_work(rec, 5, other) == 1.0e7
    with pytest.raises(ValueError, match="other units"):
        train_within(shape, placement, rec, progress=False, cache=False)
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dop.train(shape, m=12, n_jobs=1, progress=False)
        monkeypatch.setattr(work, "VERSION", work.VERSION + 1)  # the work rule changed: the cached work is not read
        _, loaded = dop.train(shape, m=12, n_jobs=1, progress=False)
    assert loaded.cache == "operator" and np.isnan(loaded.work)


def test_train_within_checks_centres_before_any_solve(bar, monkeypatch):
    from defop.training import movable as mv

    shape, placement, ref = bar
    monkeypatch.setattr(mv, "_solve_joint", lambda *a, **k: pytest.fail("solved before the check"))
    with pytest.raises(ValueError, match="centres"):
        train_within(shape, placement, ref, centres="many", progress=False, cache=False)


def test_train_within_counts_two_samples_where_one_met_the_budget(bar, monkeypatch):
    from defop.training import movable as mv

    shape, placement, ref = bar
    tiny = _record(1e-9, 12)
    tiny.work_units = ref.work_units

    def solved(shape, placement, idx, Q, *a, **k):  # per sample: work 5, 3, 3, ...; no setup
        X = np.repeat(shape.mesh.V[None], len(idx), 0) + 1e-3 * np.arange(len(idx))[:, None, None]
        spent = np.r_[5.0, np.full(len(idx) - 1, 3.0)]
        info = {"fallback": "", "work": spent, "setup": np.zeros(len(idx)), "work_units": ref.work_units}
        return X, np.ones(len(idx), bool), 0.0, 0.0, "full", info

    monkeypatch.setattr(mv, "_solve_joint", solved)
    _, rec = _within((shape, placement, tiny))
    assert len(rec.idx) == 2 and rec.work == 8.0 + 2 * work.DRAW  # both samples' solves and draws, not the first's
    from defop.training.movable_budget import fit_work

    assert rec.budget["fit"] == fit_work(2, *shape.mesh.V.shape)[0]


def test_counted_joint_solves_keep_no_checkpoint(bar, tmp_path, monkeypatch):
    """A counted truth is solved without a checkpoint: no sample is loaded without its work (NaN)."""
    from defop.training import batch
    from defop.training import movable as mv

    shape, placement, _ = bar
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    monkeypatch.setattr(batch, "Checkpoints", lambda *a, **k: pytest.fail("a checkpoint while counting"))
    idx, Q = mv.sample_joint(shape, placement, 3, np.random.default_rng(0), 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        *_, info = mv._solve_joint(shape, placement, idx, Q, "sarap", 1, False, True, "full", counted=True)
    assert np.isfinite(info["work"]).all() and info["work_units"] == work.units(shape.mesh)


def test_a_factorisation_counts_its_factor_its_hessian_and_the_iteration():
    """The work of one numeric factorisation (sixth part): its factor's nonzeros, ITERATION and HESSIAN per nonzero of
    the factorised K, so a fine iteration (larger K) counts more than a coarse one beyond its factor."""
    import scipy.sparse as sp

    from defop.variational import problem as pb
    from defop.variational import work as vwork

    mesh = dop.shapes.load("bar").mesh
    h = pb.ReducedHessian(mesh, np.arange(10, mesh.n_vertices), backend="qdldl")
    n = 2 * (mesh.n_vertices - 10)
    K = sp.triu(sp.diags([4.0] * n) + sp.diags([-1.0] * (n - 1), 1) + sp.diags([-1.0] * (n - 1), -1)).tocsc()
    before = vwork.total()
    h.factorise(K, np.ones(n))
    spent = vwork.total() - before
    assert h.factor_nnz > 0 and K.nnz == 2 * n - 1
    assert spent == h.factor_nnz + vwork.ITERATION + round(vwork.HESSIAN * K.nnz)
    h.factorise(K, np.ones(n))  # the same K again: re-used, no factorisation
    assert vwork.total() - before == pytest.approx(spent)


@pytest.mark.parametrize("bad", [(-1, 0), (1, -1), (float("nan"), 0), (1, float("inf"))])
def test_work_refuses_a_bad_count_and_counts_nothing(bad):
    from defop.variational import work as vwork

    before = vwork.total()
    with pytest.raises(ValueError, match="finite and >= 0"):
        vwork.add(*bad)
    assert vwork.total() == before


def test_a_solvers_setup_grows_with_its_mesh_and_its_factors():
    class Mesh:
        n_vertices, dim = 100, 2

    class Problem:
        mesh, biharmonic_nnz = Mesh(), 1000

        class hessian:
            factor_nnz = 200

    class Solver:
        problem = Problem()

    assert work.setup_of(Solver()) == 1000 + work.SETUP * 200 + work.SOLVER * 200
    Problem.mesh.n_vertices = 400  # four times the unknowns: the construction's part four times
    assert work.setup_of(Solver()) == 1000 + work.SETUP * 200 + work.SOLVER * 800
    assert work.setup_of(object()) == 0.0


def test_train_within_counts_each_joint_samples_draw(bar, monkeypatch):
    """A joint sample's draw is counted (work.DRAW): a draw as costly as the whole reference stops at m = 2."""
    import dataclasses

    shape, _, ref = bar
    monkeypatch.setattr(work, "DRAW", ref.work)
    again = dataclasses.replace(ref, work_units=work.units(shape.mesh))  # the reference in the patched units
    _, rec = _within((shape, bar[1], again), factor=1.5)
    assert len(rec.idx) == 2 and rec.work >= 2 * ref.work
