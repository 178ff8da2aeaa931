"""A factorisation re-used as a preconditioner: exact Newton steps on large meshes solve by CG on the last exact
step's LDLᵀ (``defop.variational.backend.pcg``) and reach the same verified minima; below the size rule (by default:
at every size) every step factorises, as before."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.training.sampling import sample_shape
from defop.variational import Solver
from defop.variational import backend as bk


@pytest.fixture(scope="module")
def bar():
    shape = dop.shapes.load("bar")
    return shape, sample_shape(shape, 3, np.random.default_rng(0))


def solve_all(shape, Q, reuse, monkeypatch):
    """Every sample from the rest pose; the CG solves that replaced a factorisation, counted."""
    used = []
    pcg = bk.pcg

    def counted(*a, **k):
        found = pcg(*a, **k)
        used.append(found is not None)
        return found

    monkeypatch.setattr(bk, "pcg", counted)
    solver = Solver(shape.mesh, shape.handles, "sarap")
    solver.hessian.reuse = reuse
    results = [solver.solve(shape.targets(q)) for q in Q]
    return results, sum(used)


def test_the_reuse_path_reaches_the_direct_paths_verified_minima(bar, monkeypatch):
    shape, Q = bar
    direct, n_direct = solve_all(shape, Q, False, monkeypatch)
    reused, n_reused = solve_all(shape, Q, True, monkeypatch)
    assert n_direct == 0
    assert n_reused > 0  # the re-use ran, and replaced factorisations
    for a, b in zip(direct, reused):
        assert a.converged and b.converged
        assert abs(b.energy - a.energy) <= 1e-9 * a.energy
        assert np.abs(b.X - a.X).max() <= 1e-6 * shape.mesh.bbox_diagonal


def test_reuse_is_off_below_the_size_rule(bar, monkeypatch):
    shape, Q = bar
    monkeypatch.delenv("DEFOP_REUSE", raising=False)
    n = len(Solver(shape.mesh, shape.handles, "sarap").free)
    monkeypatch.setattr(bk, "REUSE_MIN_UNKNOWNS", n)
    assert Solver(shape.mesh, shape.handles, "sarap").hessian.reuse
    monkeypatch.setattr(bk, "REUSE_MIN_UNKNOWNS", n + 1)
    solver = Solver(shape.mesh, shape.handles, "sarap")
    assert not solver.hessian.reuse

    def never(*a, **k):
        raise AssertionError("CG ran below the size rule")

    monkeypatch.setattr(bk, "pcg", never)
    assert solver.solve(shape.targets(Q[0])).converged  # every step factorised


def test_auto_factorises_every_step_at_every_size_measured(monkeypatch):
    monkeypatch.delenv("DEFOP_REUSE", raising=False)
    assert not bk.choose_reuse(59_468, "qdldl")  # the 29,739-vertex aleph, where re-use did not pay


@pytest.mark.parametrize("mode, small, large", [("on", True, True), ("off", False, False), ("auto", False, True)])
def test_the_environment_switches_the_reuse(mode, small, large, monkeypatch):
    monkeypatch.setenv("DEFOP_REUSE", mode)
    monkeypatch.setattr(bk, "REUSE_MIN_UNKNOWNS", 1000)
    assert bk.choose_reuse(10, "qdldl") is small
    assert bk.choose_reuse(1000, "pardiso") is large


@pytest.mark.parametrize("bad", ["yes", "1", "always"])
def test_a_bad_reuse_setting_is_a_clear_error(bad, monkeypatch):
    monkeypatch.setenv("DEFOP_REUSE", bad)
    shape = dop.shapes.load("bar")
    with pytest.raises(ValueError, match=f"DEFOP_REUSE must be one of auto, on, off, got '{bad}'"):
        Solver(shape.mesh, shape.handles, "sarap")


def test_a_pickled_solver_has_nothing_to_reuse(bar):
    shape, Q = bar
    solver = Solver(shape.mesh, shape.handles, "sarap")
    solver.hessian.reuse = True
    solver.solve(shape.targets(Q[0]))
    copy = pickle.loads(pickle.dumps(solver))
    assert copy.hessian.reuse and not copy.hessian._stale and copy.hessian._stalled == 0


@settings(max_examples=25, deadline=None)
@given(n=st.integers(2, 30), seed=st.integers(0, 2**31 - 1))
def test_pcg_solves_spd_systems_and_stalls_on_indefinite_ones(n, seed):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    b = rng.normal(size=n)
    upper = sp.csc_matrix(np.triu(K))
    x, its = bk.pcg(upper, b, lambda r: np.linalg.solve(K, r), 1e-10, 5)  # the exact preconditioner: one step
    assert its == 1 and np.allclose(K @ x, b, rtol=1e-8, atol=1e-8)
    x, _ = bk.pcg(upper, b, lambda r: r, 1e-10, 10 * n)
    assert np.linalg.norm(K @ x - b) <= 1e-9 * np.linalg.norm(b)
    indefinite = sp.csc_matrix(np.triu(-K))
    assert bk.pcg(indefinite, b, lambda r: r, 1e-10, 10 * n) is None
    assert bk.pcg(upper, b, lambda r: r, 1e-14, 0) is None  # no iteration allowed: a stall
