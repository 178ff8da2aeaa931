"""Multilevel training (issue 36): coarse mesh and prolongation, the policy, its safeguard, caching, determinism."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.geometry.coarse import CoarseningError, coarse_mesh_of, prolongate, prolongation
from defop.geometry.mesh import Mesh
from defop.training import ground_truths
from defop.training import multilevel as ml
from defop.variational.solver import Solver


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=400)


@pytest.fixture(scope="module")
def levels(bar):
    return ml.coarse_level(bar)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))


# ---------------------------------------------------------------- geometry: coarse mesh and prolongation
@pytest.mark.parametrize("name", ["bar", "u_shape", "aleph", "octopus"])
def test_coarse_mesh_keeps_the_handles_and_the_shape(name):
    shape = dop.shapes.load(name)
    lv = ml.coarse_level(shape)
    fine, coarse = shape.mesh, lv.coarse.mesh
    assert 0.08 < coarse.n_vertices / fine.n_vertices < 0.5
    assert np.array_equal(coarse.V[lv.coarse.handles], fine.V[shape.handles])  # the same points, bit for bit
    assert np.array_equal(lv.coarse.moving, shape.moving)
    assert abs(coarse.areas.sum() / fine.areas.sum() - 1) < 0.02  # the same shape (outline resampled coarser)


@pytest.mark.parametrize("name", ["bar", "aleph"])
def test_prolongation_is_exact_at_rest_and_on_handles(name):
    shape = dop.shapes.load(name)
    lv = ml.coarse_level(shape)
    Vc = lv.coarse.mesh.V
    assert np.array_equal(lv.prolongate(Vc), shape.mesh.V)  # rest pose -> rest pose, bit for bit
    rng = np.random.default_rng(7)
    Xc = Vc + 0.05 * rng.standard_normal(Vc.shape)
    X = lv.prolongate(Xc)
    assert np.array_equal(X[shape.handles], Xc[lv.coarse.handles])  # handles -> handles, bit for bit
    # barycentric: affine maps are reproduced everywhere, also where a fine vertex is just outside the coarse mesh
    A, b = np.array([[1.1, 0.3], [-0.2, 0.9]]), np.array([0.4, -1.0])
    X = lv.prolongate(Vc @ A.T + b)
    assert np.abs(X - (shape.mesh.V @ A.T + b)).max() < 1e-12 * shape.mesh.bbox_diagonal * 100
    P = lv.P
    assert np.allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0, atol=1e-12)


@given(st.integers(0, 2**31 - 1), st.lists(st.integers(0, 3), min_size=1, max_size=4, unique=True))
def test_prolongation_any_handle_subset_and_order(seed, order):
    """Handles in any order and subset go to their coarse vertices exactly (a stranger's handle sets)."""
    shape = dop.shapes.load("u_shape", n_vertices=400)
    lv = ml.coarse_level(shape)
    rng = np.random.default_rng(seed)
    Xc = lv.coarse.mesh.V + 0.1 * rng.standard_normal(lv.coarse.mesh.V.shape)
    fh, ch = shape.handles[order], lv.coarse.handles[order]
    X = prolongate(lv.P, shape.mesh.V, lv.coarse.mesh.V, Xc, fh, ch)
    assert np.array_equal(X[fh], Xc[ch])


def test_coarse_mesh_refusals(bar):
    # 3D: a coarse Kuhn grid of fewer than the minimum of vertices
    solid = dop.shapes.load("bar_3d", n_vertices=300)
    with pytest.raises(CoarseningError, match="saves nothing"):
        coarse_mesh_of(solid.mesh, solid.outline, solid.P, 8, 150)
    # a mesh without an outline
    with pytest.raises(CoarseningError, match="outline"):
        coarse_mesh_of(bar.mesh, [], bar.P, 2.5, 20)
    # a coarse mesh that saves nothing
    with pytest.raises(CoarseningError, match="saves nothing"):
        coarse_mesh_of(bar.mesh, bar.outline, bar.P, 1.5, 20)
    # a coarse mesh that loses a part of the shape: fine vertices far outside it
    far = Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.array([[0, 1, 2]]))
    with pytest.raises(CoarseningError, match="outside the coarse mesh"):
        prolongation(np.array([[0.2, 0.2], [3.0, 3.0]]), far)


def test_policy_falls_back_to_one_level_and_says_so(bar):
    solid = dop.shapes.load("bar_3d", n_vertices=300)
    with pytest.warns(ml.MultilevelWarning, match="one level"):
        used, lv, why = ml.choose(solid, "multilevel")
    assert used == "full" and lv is None and "saves nothing" in why
    nameless = dop.shapes.Shape("no outline", bar.mesh, bar.handles, bar.moving, bar.regions)
    with pytest.warns(ml.MultilevelWarning):
        assert ml.choose(nameless, "multilevel")[0] == "full"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert ml.choose(bar, "multilevel")[0] == "multilevel"
    with pytest.raises(ValueError, match="policy"):
        dop.train(bar, m=10, policy="coarse", progress=False)


def test_auto_falls_back_in_3d_without_a_warning_and_records_why():
    """``auto`` on a tet mesh too small for a coarse level: one level, the reason in the record, no warning in a
    lesson."""
    solid = dop.shapes.load("bar_3d", n_vertices=300)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ml.MultilevelWarning)
        op, rec = dop.train(
            solid, "arap", "linear", m=13, n_jobs=1, progress=False, policy="auto", cache=False, rounds=1
        )
    assert rec.policy == "full" and "saves nothing" in rec.multilevel["fallback"] and op.meta["policy"] == "full"


@settings(max_examples=6, deadline=None)
@given(n=st.integers(200, 700))
def test_auto_is_multilevel_wherever_a_coarse_mesh_exists(n):
    """``auto`` picks two levels at any size where a coarse mesh exists (keyed on that, not on the dimension or a
    vertex count), one level without a warning and with the reason where none does (too few vertices to save)."""
    shape = dop.shapes.load("bar", n_vertices=n)
    try:
        ml.coarse_level(shape)
        exists, reason = True, ""
    except CoarseningError as exc:
        exists, reason = False, str(exc)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ml.MultilevelWarning)
        used, lv, why = ml.choose(shape, "auto")
    assert (used, lv is not None, why) == (("multilevel", True, "") if exists else ("full", False, reason))
    if shape.mesh.n_vertices >= 2 * ml.MIN_COARSE_VERTICES + 20:
        assert exists  # every small 2D shape that can save has its coarse mesh: auto is multilevel there


# ---------------------------------------------------------------- the policy
def _verified(shape, rec):
    s = Solver(shape.mesh, shape.handles, "sarap")
    return all(s.verify(X, s.targets_of(shape.targets(q))).ok for q, X in zip(rec.samples, rec.X))


@pytest.mark.parametrize("policy", ["full", "multilevel", "auto"])
def test_every_sample_a_verified_minimum_under_every_policy(bar, policy):
    op, rec = dop.train(bar, m=14, seed=3, n_jobs=1, progress=False, policy=policy)
    assert rec.converged.all() and _verified(bar, rec)
    used = "multilevel" if policy == "auto" else policy  # a 400-vertex bar has a coarse mesh
    assert rec.policy == used and op.meta["policy"] == used and rec.params["policy"] == policy
    if used == "multilevel":
        info = rec.multilevel
        assert len(info["rule"]) == 14 and set(info["rule"]) <= {"", *ml.RULES}
        assert info["coarse_vertices"] == ml.coarse_level(bar).coarse.mesh.n_vertices
        assert all(k >= 1 for k in info["minima"])
        assert op.meta["safeguard_fired"] == sum(rec.safeguard.values())
        assert set(rec.stage_times) >= {"coarse", "fine", "fit"}
    else:
        assert rec.safeguard == {} and "rule" not in rec.multilevel


def test_same_minima_as_the_full_policy(bar):
    """On the bar (a sample may buckle up or down) multilevel ends on main's minima, sample by sample."""
    _, full = dop.train(bar, m=24, seed=5, n_jobs=1, progress=False, policy="full", cache=False)
    _, two = dop.train(bar, m=24, seed=5, n_jobs=1, progress=False, policy="multilevel", cache=False)
    s = Solver(bar.mesh, bar.handles, "sarap")
    Ef, Em = (np.array([s.energy_of(X) for X in r.X]) for r in (full, two))
    rel = (Em - Ef) / np.maximum(Ef, 1e-3 * np.median(Ef))
    assert (rel > 1e-6).sum() == 0, rel  # no sample higher than the full policy's minimum


def test_round_two_verifies_the_incumbent_instead_of_re_solving(bar, monkeypatch):
    """The current solution is verified (no local solve from it) and kept where the smooth fit's start ends higher."""
    Q = dop.training.sampling.sample_shape(bar, 3, np.random.default_rng(2))
    X, conv = dop.training.solve_samples(bar, Q, progress=False, n_jobs=1)
    starts = []
    real = Solver.solve_best

    def spy(self, T, starts=(), rest=True, **kw):
        starts_seen.append([s for s in starts if s is not None])
        return real(self, T, starts=starts, rest=rest, **kw)

    starts_seen = starts
    monkeypatch.setattr(Solver, "solve_best", spy)
    X2, c2 = dop.training.solve_samples(bar, Q, n_jobs=1, progress=False, rest=False, X0=[bar.mesh.V] * 3, incumbents=X)
    assert c2.all() and all(len(s) == 1 and np.array_equal(s[0], bar.mesh.V) for s in starts_seen)
    s = Solver(bar.mesh, bar.handles, "sarap")
    for x, x2 in zip(X, X2):  # the lower of the two verified minima; the incumbent wins ties
        assert s.energy_of(x2) <= s.energy_of(x) and (np.array_equal(x2, x) or s.energy_of(x2) < s.energy_of(x))
    # no other start and no rest pose: the verified incumbent as it is, no solve at all
    starts_seen.clear()
    X3, c3 = dop.training.solve_samples(bar, Q, n_jobs=1, progress=False, rest=False, incumbents=X)
    assert c3.all() and np.array_equal(X3, X) and starts_seen == []


# ---------------------------------------------------------------- the safeguard on a constructed bistable case
def _branches(shape, dy):
    """The bar pushed in by 0.12 with its end dy off the axis: the up- and the down-buckled verified minima."""
    s = Solver(shape.mesh, shape.handles, "sarap")
    p = shape.P_moving[0]
    up = s.solve(shape.targets(np.array([[p[0] - 0.12, p[1] + 0.06]]))).X
    down = s.solve(shape.targets(np.array([[p[0] - 0.12, p[1] - 0.06]]))).X
    T = shape.targets(np.array([[p[0] - 0.12, p[1] + dy]]))
    return T, s.solve(T, X0=up), s.solve(T, X0=down)


def test_safeguard_fires_where_the_coarse_mesh_picks_the_wrong_minimum(bar, levels, monkeypatch):
    T, up, down = _branches(bar, 0.0)
    _, cup, cdown = _branches(levels.coarse, 0.0)
    assert up.converged and down.converged and cup.converged and cdown.converged
    assert np.abs(up.X - down.X).max() > 0.05  # two distinct branches on both meshes
    # the premise, measured: the coarse mesh ranks the branches the other way round from the fine mesh
    assert cup.energy < cdown.energy and down.energy < up.energy
    solver = Solver(bar.mesh, bar.handles, "sarap")
    single = solver.solve(T, X0=levels.prolongate(cup.X))  # what one fine run from the coarse winner gives
    assert single.converged and single.energy > down.energy * (1 + 1e-4)  # the wrong (higher) minimum
    cands = [(cup.X, cup.energy, True), (cdown.X, cdown.energy, True)]
    X, ok, rule, *_ = ml.refine_one(levels, solver, T, cands)
    assert ok and rule == "margin" and abs(solver.energy_of(X) - down.energy) <= 1e-6 * down.energy
    monkeypatch.setattr(ml, "MARGIN", 0.0)  # without the margin rule the fine evaluations still catch it
    X, ok, rule, *_ = ml.refine_one(levels, solver, T, cands)
    assert ok and rule == "rank" and abs(solver.energy_of(X) - down.energy) <= 1e-6 * down.energy


def test_safeguard_rules_flip_and_iterations(bar, levels, monkeypatch):
    solver = Solver(bar.mesh, bar.handles, "sarap")
    p = bar.P_moving[0]
    T = bar.targets(np.array([[p[0] - 0.05, p[1] + 0.1]]))
    c = Solver(levels.coarse.mesh, levels.coarse.handles, "sarap").solve(T)
    X, ok, rule, iters, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, True)])
    assert ok and rule == "" and 0 < iters <= ml.MAX_FINE_ITERATIONS
    monkeypatch.setattr(ml, "MAX_FINE_ITERATIONS", iters - 1)
    X2, ok, rule, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, True)])
    assert ok and rule == "iterations" and solver.energy_of(X2) <= solver.energy_of(X) * (1 + 1e-6)
    folded = c.X.copy()  # a coarse "minimum" folded over: its prolongation flips fine triangles
    folded[:, 1] = 2 * folded[levels.coarse.handles].mean(0)[1] - folded[:, 1]
    folded[levels.coarse.handles] = c.X[levels.coarse.handles]
    X3, ok, rule, *_ = ml.refine_one(levels, solver, T, [(folded, c.energy, True)])
    assert ok and rule == "flip"
    _, ok, rule, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, False)])
    assert ok and rule == "coarse"  # no verified coarse minimum: the fine portfolio


def test_the_fallback_does_not_run_the_single_start_again(bar, levels, monkeypatch):
    """Where the single fine run fires a rule, the full fine portfolio runs every other start and the rest pose, not
    the single run's start again (a solve is deterministic), and keeps the minimum it kept before, bit for bit."""
    solver = Solver(bar.mesh, bar.handles, "sarap")
    p = bar.P_moving[0]
    T = bar.targets(np.array([[p[0] - 0.05, p[1] + 0.1]]))
    c = Solver(levels.coarse.mesh, levels.coarse.handles, "sarap").solve(T)
    S0 = levels.prolongate(c.X)
    full = solver.solve_best(T, starts=[S0], rest=True)  # the full portfolio with the single run's start in it
    monkeypatch.setattr(ml, "MAX_FINE_ITERATIONS", 0)
    real, seen = Solver.solve, []

    def spy(self, targets, X0=None, **kw):
        seen.append(X0)
        return real(self, targets, X0=X0, **kw)

    monkeypatch.setattr(Solver, "solve", spy)
    X, ok, rule, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, True)])
    assert ok and rule == "iterations" and np.array_equal(X, full.X)
    assert len(seen) == 2 and sum(X0 is not None and np.array_equal(X0, S0) for X0 in seen) == 1


def test_safeguard_rest_catches_a_single_run_above_the_rest_pose_start(bar, levels, monkeypatch):
    """A single fine run that ends above the rest pose's start at the targets (here: its energy raised, as a fine
    run stuck on a higher branch would be) falls back to the fine portfolio, which ends on the rest-pose minimum."""
    solver = Solver(bar.mesh, bar.handles, "sarap")
    p = bar.P_moving[0]
    T = bar.targets(np.array([[p[0] - 0.05, p[1] + 0.1]]))
    c = Solver(levels.coarse.mesh, levels.coarse.handles, "sarap").solve(T)
    rest = solver.solve(T)
    bound = ml.rest_start_energy(solver, T)
    assert np.isfinite(bound) and rest.energy <= bound
    real = Solver.solve_best

    def higher(self, T, starts=(), rest=True, **kw):
        r = real(self, T, starts=starts, rest=rest, **kw)
        return r if rest else dataclasses.replace(r, energy=bound * (1 + 1e-5))

    monkeypatch.setattr(Solver, "solve_best", higher)
    X, ok, rule, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, True)])
    assert ok and rule == "rest" and abs(solver.energy_of(X) - rest.energy) <= 1e-6 * rest.energy
    monkeypatch.setattr(ml, "REST_TOLERANCE", 1e-4)  # within the tolerance: the single run stands
    _, ok, rule, *_ = ml.refine_one(levels, solver, T, [(c.X, c.energy, True)])
    assert ok and rule == ""


@settings(max_examples=8, deadline=None)
@given(dx=st.floats(-0.1, 0.1), dy=st.floats(-0.15, 0.15))
def test_rest_start_energy_bounds_a_one_stage_rest_pose_solve(bar, dx, dy):
    """The rule's premise: a rest-pose solve taken in one continuation stage ends no higher than its start."""
    solver = Solver(bar.mesh, bar.handles, "sarap")
    p = bar.P_moving[0]
    T = bar.targets(np.array([[p[0] + dx, p[1] + dy]]))
    r, bound = solver.solve(T), ml.rest_start_energy(solver, T)
    assert r.converged
    if "continuation stages" not in r.reason:
        assert np.isfinite(bound) and r.energy <= bound * (1 + 1e-12) + 1e-15


# ---------------------------------------------------------------- caching and determinism
def test_policy_in_the_cache_keys(bar):
    a, ra = dop.train(bar, m=12, seed=4, n_jobs=1, progress=False, policy="full")
    b, rb = dop.train(bar, m=12, seed=4, n_jobs=1, progress=False, policy="multilevel")
    assert ra.cache == "none" and rb.cache == "none"  # not the full policy's entry
    c, rc = dop.train(bar, m=12, seed=4, n_jobs=1, progress=False, policy="multilevel")
    assert rc.cache == "operator" and rc.policy == "multilevel" and c.meta["policy"] == "multilevel"
    assert rc.multilevel["rule"] == rb.multilevel["rule"]  # the decisions come back with the cached ground truth
    d, rd = dop.train(bar, m=12, seed=4, n_jobs=1, progress=False, policy="auto")
    assert rd.cache == "operator" and rd.policy == "multilevel"  # auto chose multilevel: that policy's entry
    assert rd.params["policy"] == "auto" and np.array_equal(d.W, c.W)
    lv = ml.coarse_level(bar)
    keys = {
        ground_truths.train_key(bar, "sarap", ra.samples, 2, p, lv if p == "multilevel" else None)
        for p in ("full", "multilevel")
    }
    assert len(keys) == 2


def test_same_operator_for_any_n_jobs(bar):
    a, ra = dop.train(bar, m=12, seed=6, n_jobs=1, progress=False, policy="multilevel", cache=False)
    b, rb = dop.train(bar, m=12, seed=6, n_jobs=2, progress=False, policy="multilevel", cache=False)
    Q = dop.training.sampling.sample_shape(bar, 20, np.random.default_rng(99))
    assert np.abs(a(Q) - b(Q)).max() <= 1e-9 * bar.mesh.bbox_diagonal
    assert ra.multilevel["rule"] == rb.multilevel["rule"]


def test_interrupted_multilevel_training_resumes_where_it_stopped(bar, monkeypatch):
    """The fine runs are checkpointed every 25 samples under the policy's key: a run killed at sample 27 refines
    only the last 5 again, and returns what an uninterrupted one does."""
    _, ref = dop.train(bar, m=30, seed=8, n_jobs=1, progress=False, policy="multilevel", cache=False)
    calls, real = [], ml.refine_one

    class Killed(RuntimeError):
        pass

    def flaky(*args, **kw):
        calls.append(1)
        if len(calls) == 27:
            raise Killed
        return real(*args, **kw)

    monkeypatch.setattr(ml, "refine_one", flaky)
    with pytest.raises(Killed):
        dop.train(bar, m=30, seed=8, n_jobs=1, progress=False, policy="multilevel")
    calls.clear()
    _, rec = dop.train(bar, m=30, seed=8, n_jobs=1, progress=False, policy="multilevel")
    assert len(calls) == 5 and rec.cache == "none"
    assert np.array_equal(rec.X, ref.X) and rec.multilevel["rule"] == ref.multilevel["rule"]
    assert rec.multilevel["iterations"] == ref.multilevel["iterations"]


def test_same_operator_with_dask(bar):
    pytest.importorskip("dask.distributed")
    import joblib
    from dask.distributed import Client, LocalCluster

    a, ra = dop.train(bar, m=12, seed=6, n_jobs=1, progress=False, policy="multilevel", cache=False)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with Client(cluster), joblib.parallel_backend("dask"):
            b, rb = dop.train(bar, m=12, seed=6, n_jobs=-1, progress=False, policy="multilevel", cache=False)
    Q = dop.training.sampling.sample_shape(bar, 20, np.random.default_rng(99))
    assert np.abs(a(Q) - b(Q)).max() <= 1e-9 * bar.mesh.bbox_diagonal and ra.multilevel["rule"] == rb.multilevel["rule"]


def test_multilevel_modules_are_exported():
    """train's docstring names defop.training.multilevel.MultilevelWarning: the multilevel policy and the coarse
    meshes are in their subpackage's ``__all__`` as the other modules are."""
    import defop.geometry as geometry
    import defop.training as training

    assert "multilevel" in training.__all__ and "coarse" in geometry.__all__
    assert training.multilevel.MultilevelWarning is ml.MultilevelWarning
    assert geometry.coarse.coarse_mesh_of is coarse_mesh_of


def test_training_seconds_count_the_multilevel_stages(bar):
    """Table 1's preprocess seconds and the adaptive record count the coarse and fine stages, not only fit/fold."""
    from defop.training.solves import training_cpu

    assert training_cpu({"coarse": 1.0, "fine": 2.0, "fit": 0.25, "fold": 0.75, "load": 9.0}) == 4.0
    op, rec = dop.train(bar, m=14, seed=3, n_jobs=1, progress=False, policy="multilevel", cache=False)
    Q = dop.training.sampling.sample_shape(bar, 3, np.random.default_rng(1))
    row = dop.analysis.timing_row(bar, op, rec, Q, "hat", tol=1e-3)
    t = op.meta["stage_times"]
    assert {"coarse", "fine"} <= set(t) and row["preprocess_s"] == pytest.approx(sum(t.values()))


def test_the_record_places_the_fine_stage_cpu_sample_by_sample(bar):
    """``record.multilevel["cpu"]``: each sample's fine-stage CPU seconds (single run, checks, any fallback), which
    add up to the fine stage's (bench_training places a training's CPU by safeguard rule with them)."""
    _, rec = dop.train(bar, m=14, seed=3, n_jobs=1, progress=False, policy="multilevel", cache=False)
    cpu = np.array(rec.multilevel["cpu"])
    assert cpu.shape == (14,) and np.all(cpu > 0)
    assert cpu.sum() <= rec.stage_times["fine"] + 1e-6


def test_handles_on_the_outline_keep_a_fixed_p_training_on_one_level():
    """A fixed-P shape whose handles are boundary vertices (automatic handles of an outline) has no coarse level, as
    before movable regions could put points on the coarse outline: its training policy and minima stay as they
    were (auto chose multilevel on a 192-vertex coarse star for a moment)."""
    t = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    r = np.where(np.arange(10) % 2 == 0, 1.0, 0.45)
    star = dop.shapes.from_polygon(np.c_[r * np.cos(t), r * np.sin(t)], n_vertices=1500, name="star")
    assert np.isin(star.handles, star.mesh.boundary_vertices).any()
    used, level, why = ml.choose(star, "auto")
    assert (used, level) == ("full", None)
    assert "boundary" in why or "outline" in why
