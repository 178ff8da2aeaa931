"""The 3D Newton schedule and the factorisation it does not repeat: S-ARAP on tetrahedra starts with the held μ = 0
stage (no smoothed stage), 2D keeps its μ = 1e-5 stage, and a matrix equal to the last one factorised is solved
with the factors already made."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import reference3d as r3
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.training import cache as cm
from defop.variational import Solver
from defop.variational import backend as bk
from defop.variational.solver import SMOOTHING, SMOOTHING_3D


def _grid_problem(seed):
    """A 3×3×3 grid of tets, the two end faces' vertices as handles moved by up to 0.15 (random order)."""
    rng = np.random.default_rng(seed)
    V, T = r3.grid_tets(3)
    h = rng.permutation(np.flatnonzero((V[:, 0] == V[:, 0].min()) | (V[:, 0] == V[:, 0].max())))
    return dop.Mesh(V, T), h, V[h] + rng.uniform(-0.15, 0.15, (len(h), 3))


def test_sarap_defaults_to_the_held_stage_in_3d_and_keeps_the_smoothed_stage_in_2d():
    mesh, h, _ = _grid_problem(0)
    assert SMOOTHING_3D == (0.0,) and Solver(mesh, h, "sarap").mu_schedule == (0.0,)
    bar = dop.shapes.load("bar")
    assert SMOOTHING == (1e-5,) and Solver(bar.mesh, bar.handles, "sarap").mu_schedule == (1e-5, 0.0)
    # an explicit schedule is kept in either dimension, with no fallback
    explicit = Solver(mesh, h, "sarap", smoothing=(1e-5,))
    assert explicit.mu_schedule == (1e-5, 0.0) and not hasattr(explicit, "fallback_schedule")
    # 2D's settings (its cache keys) are what they were
    assert set(cm.solver_settings(Solver(bar.mesh, bar.handles, "sarap"))) == {
        "barrier",
        "class",
        "energy",
        "exact_switch",
        "max_escapes",
        "max_iter",
        "mu_schedule",
        "stage_tol",
        "tol",
        "verify_tol",
    }


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_the_3d_default_reaches_the_smoothed_schedules_verified_minimum(seed):
    """Users move the handles anywhere: the held μ = 0 stage alone ends on the minimum the (1e-5, 0) schedule finds."""
    mesh, h, targets = _grid_problem(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        new = Solver(mesh, h, "sarap").solve(targets)
        old = Solver(mesh, h, "sarap", smoothing=(1e-5,)).solve(targets)
    assert new.converged and old.converged, (new.reason, old.reason)
    assert abs(new.energy - old.energy) <= 1e-7 * old.energy
    assert np.abs(new.X - old.X).max() <= 1e-4 * mesh.bbox_diagonal


class _Counting:
    """A back end's factorisation object that counts numeric factorisations (qdldl's update, PARDISO's factor)."""

    def __init__(self, inner):
        self.inner, self.count = inner, 0

    def update(self, *args, **kw):
        self.count += 1
        return self.inner.update(*args, **kw)

    def factor(self, *args, **kw):
        self.count += 1
        return self.inner.factor(*args, **kw)

    def __getattr__(self, name):
        return getattr(self.inner, name)


BACKENDS = ["qdldl"] + (["pardiso"] if bk.HAVE_PARDISO and bk.mkl_error() is None else [])


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_same_matrix_again_is_solved_with_the_factors_already_made(backend):
    mesh, h, targets = _grid_problem(1)
    s = Solver(mesh, h, "sarap", backend=backend)
    X = mesh.V.copy()
    X[s.handles] = s.targets_of(targets)
    _, g, data, _ = s.grad_hess(X, 0.0, project=False)
    gf = g[s.free]
    p = s.newton_direction(gf, data, rel_shift=1e-8)
    negative = s.hessian.inertia()
    s.hessian._factor = counting = _Counting(s.hessian._factor)
    again = s.newton_direction(gf, data.copy(), rel_shift=1e-8)  # equal values, another array
    assert counting.count == 0
    assert np.array_equal(again, p) and s.hessian.inertia() == negative  # the same solution and inertia, bit for bit
    s.newton_direction(gf, data, rel_shift=1e-6)  # another shift: another matrix
    assert counting.count == 1


def _pinned_box():
    """A 4×4×4 grid with every boundary vertex pinned to a 0.7 scaling about the centroid: the held μ = 0 stage does
    not converge within HELD_FIRST_ITERATIONS there (every tet sits on the kink σ₁ = σ₂ = σ₃)."""
    V, T = r3.grid_tets(4)
    c = V.mean(axis=0)
    h = np.flatnonzero(np.any((V == V.min(axis=0)) | (V == V.max(axis=0)), axis=1))
    return dop.Mesh(V, T), h, c + 0.7 * (V[h] - c)


def test_the_3d_fallback_schedule_runs_where_the_held_stage_stalls(monkeypatch):
    from defop.variational import newton

    mesh, h, targets = _pinned_box()
    seen, real = [], newton._schedule
    monkeypatch.setattr(
        newton, "_schedule", lambda s, log, X, tol, sched: seen.append(tuple(sched)) or real(s, log, X, tol, sched)
    )
    result = Solver(mesh, h, "sarap").solve(targets)
    assert result.converged
    assert seen[:2] == [(0.0,), (1e-5, 0.0)]


def test_a_fallback_result_counts_both_attempts():
    """Where the held-first solve ends unverified, the fallback's result counts both attempts: iterations, time and
    histories (it kept only the fallback's time and histories)."""
    mesh, h, targets = _grid_problem(2)
    s = Solver(mesh, h, "sarap")
    real, runs = s._path, []

    def path(*args):  # the first attempt is reported unverified, as a stalled kink would leave it
        result = real(*args)
        runs.append(dataclasses.replace(result))  # a copy: what the attempt returned, whatever happens to it after
        return dataclasses.replace(result, converged=False) if len(runs) == 1 else result

    s._path = path
    result = s.solve(targets)
    first, again = runs
    assert result.converged and len(runs) == 2
    assert result.iterations == first.iterations + again.iterations
    assert result.time == first.time + again.time
    assert np.array_equal(result.energy_history, np.concatenate([first.energy_history, again.energy_history]))
    assert len(result.time_history) == len(result.energy_history) and np.all(np.diff(result.time_history) >= 0)
    assert np.array_equal(result.X, again.X)


@pytest.mark.parametrize("max_iter", [1, 2, 3, 7])
def test_the_3d_fallback_shares_the_iteration_budget(max_iter):
    """The fallback schedule runs on the iterations left: a solve never takes more than max_iter (it took 2x)."""
    mesh, h, targets = _grid_problem(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = Solver(mesh, h, "sarap").solve(targets, max_iter=max_iter)
    assert result.iterations <= max_iter
    if not result.converged:
        assert str(max_iter) in result.reason
