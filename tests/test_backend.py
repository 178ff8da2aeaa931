"""The factorisation back ends (issue 27 §2, issue 28 §1): qdldl and MKL PARDISO give the same verified minima.

PARDISO is the optional ``mkl`` extra (pypardiso, x86-64): its tests skip when it is not installed. References:
numpy's dense eigenvalues for the inertia, qdldl's solve for the minima.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference3d as r3
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.variational import Solver
from defop.variational import backend as pb

needs_pardiso = pytest.mark.skipif(not pb.HAVE_PARDISO, reason="pypardiso (the mkl extra) is not installed")


@pytest.mark.parametrize("bad", ["mkl", "", "QDLDL2", 3, None])
def test_an_unknown_backend_is_a_clear_error(bad, monkeypatch):
    mesh = dop.Mesh(*r3.grid_tets(2))
    handles = [0, 1, 2, 5]
    if bad is None:  # through the environment
        monkeypatch.setenv("DEFOP_BACKEND", "cholmod")
        with pytest.raises(ValueError, match="DEFOP_BACKEND must be one of auto, qdldl, pardiso, got 'cholmod'"):
            Solver(mesh, handles)
        return
    with pytest.raises(ValueError, match="backend must be one of auto, qdldl, pardiso"):
        Solver(mesh, handles, backend=bad)


@pytest.mark.parametrize("threads", ["abc", "0", "-2", "1.5"])
def test_a_bad_mkl_thread_count_is_refused_when_the_solver_is_built(threads, monkeypatch):
    monkeypatch.setenv("DEFOP_MKL_THREADS", threads)
    with pytest.raises(ValueError, match=f"DEFOP_MKL_THREADS must be a whole number of threads >= 1, got '{threads}'"):
        Solver(dop.Mesh(*r3.grid_tets(2)), [0, 1, 2, 5])


def test_pardiso_without_pypardiso_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(pb, "HAVE_PARDISO", False)
    with pytest.raises(ValueError, match="needs pypardiso"):
        pb.check_backend("pardiso")
    assert pb.choose_backend("auto", 10**5, 3) == "qdldl"  # auto falls back


@pytest.mark.parametrize("d", [2, 3])
def test_auto_keeps_qdldl_in_2d_and_on_small_tet_meshes(d, monkeypatch):
    monkeypatch.delenv("DEFOP_BACKEND", raising=False)
    assert pb.choose_backend(None, 100, d) == "qdldl"
    big = pb.choose_backend(None, pb.PARDISO_MIN_VERTICES_3D, d)
    assert big == ("pardiso" if d == 3 and pb.HAVE_PARDISO else "qdldl")
    monkeypatch.setenv("DEFOP_BACKEND", "qdldl")
    assert pb.choose_backend(None, 10**5, 3) == "qdldl"


@needs_pardiso
@settings(max_examples=10, deadline=None)
@given(n=st.integers(2, 40), seed=st.integers(0, 2**16), density=st.floats(0.05, 0.5))
def test_pardiso_inertia_is_the_negative_eigenvalue_count(n, seed, density):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density, random_state=rng)
    A = (A + A.T + sp.diags(rng.uniform(-2, 2, n) + np.where(rng.random(n) < 0.5, 1.0, -1.0))).tocsc()
    ev = np.linalg.eigvalsh(A.toarray())
    if np.abs(ev).min() < 1e-6 * np.abs(ev).max():
        return  # near-singular: the count is not well defined
    U = sp.triu(A, format="csc")
    U.sort_indices()
    f = pb.PardisoLDL(U)
    f.factor(U)
    b = rng.standard_normal(n)
    assert f.inertia() == int(np.count_nonzero(ev < 0))
    assert np.linalg.norm(A @ f.solve(b) - b) <= 1e-9 * np.linalg.norm(b) * np.abs(ev).max() / np.abs(ev).min()


def _both(mesh, handles, targets, energy="sarap", **kw):
    out = {}
    for backend in ("qdldl", "pardiso"):
        solver = Solver(mesh, handles, energy, backend=backend)
        for name, value in kw.items():
            setattr(solver, name, value)
        assert solver.hessian.backend == backend
        out[backend] = solver.solve(targets)
    return out["qdldl"], out["pardiso"]


def _assert_same_minimum(mesh, a, b):
    assert a.converged and b.converged, (a.reason, b.reason)
    assert abs(a.energy - b.energy) <= 1e-9 * abs(a.energy)
    assert np.abs(a.X - b.X).max() <= 1e-6 * mesh.bbox_diagonal


@needs_pardiso
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**16), energy=st.sampled_from(["arap", "sarap"]))
def test_both_backends_give_the_same_minimum_in_2d(seed, energy):
    rng = np.random.default_rng(seed)
    shape = dop.shapes.load("aleph", n_vertices=400)
    h = rng.permutation(shape.handles)
    targets = shape.mesh.V[h] + 0.08 * shape.mesh.bbox_diagonal * rng.uniform(-1, 1, (len(h), 2))
    a, b = _both(shape.mesh, h, targets, energy)
    _assert_same_minimum(shape.mesh, a, b)


@needs_pardiso
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**16), energy=st.sampled_from(["arap", "sarap"]))
def test_both_backends_give_the_same_minimum_in_3d(seed, energy):
    rng = np.random.default_rng(seed)
    V, T = r3.grid_tets(3)
    mesh = dop.Mesh(V, T)
    h = rng.permutation(np.flatnonzero((V[:, 0] == V[:, 0].min()) | (V[:, 0] == V[:, 0].max())))
    targets = V[h] + rng.uniform(-0.15, 0.15, (len(h), 3))
    a, b = _both(mesh, h, targets, energy)
    _assert_same_minimum(mesh, a, b)


@needs_pardiso
def test_pardiso_finds_the_compressed_bars_saddle_by_its_inertia():
    """A compressed bar's straight state is a saddle: PARDISO's inertia flags it as qdldl's negative pivots do."""
    V, T = r3.box_tets((12, 2, 2), (6.0, 1.0, 1.0))
    mesh = dop.Mesh(V, T)
    b = np.flatnonzero((V[:, 0] == 0) | (V[:, 0] == 6))
    targets = V[b].copy()
    targets[targets[:, 0] == 6, 0] = 6 * 0.74
    with pytest.warns(dop.variational.NotConvergedWarning, match="saddle"):
        q, p = _both(mesh, b, targets, max_escapes=0)
    for r in (q, p):
        assert not r.converged and "negative eigenvalue" in r.reason
    assert abs(q.energy - p.energy) <= 1e-9 * q.energy
    q, p = _both(mesh, b, targets)  # with escapes: both buckle, to one of two mirror-image minima of equal energy
    assert q.converged and p.converged and "escape" in p.start
    assert abs(q.energy - p.energy) <= 1e-9 * q.energy


@needs_pardiso
def test_a_pickled_pardiso_solver_rebuilds_its_factorisation_and_solves_alike():
    """joblib ships solvers to workers: the MKL handle is not pickled, the copy factorises afresh."""
    import pickle

    V, T = r3.grid_tets(2)
    mesh = dop.Mesh(V, T)
    h = np.flatnonzero(V[:, 0] == 0).tolist() + [int(np.argmax(V.sum(1)))]
    targets = V[h] + np.array([0.0, 0.0, 0.0])[None] + 0.1 * (np.arange(len(h)) == len(h) - 1)[:, None]
    solver = Solver(mesh, h, "sarap", backend="pardiso")
    first = solver.solve(targets)
    copy = pickle.loads(pickle.dumps(solver))
    assert copy.hessian.backend == "pardiso" and copy.hessian._factor is None
    again = copy.solve(targets)
    assert first.converged and again.converged
    assert np.array_equal(first.X, again.X)


@needs_pardiso
def test_a_matrix_pardiso_cannot_factorise_gives_nan_not_an_exception():
    U = sp.triu(sp.csc_matrix(np.array([[1.0, 2.0], [2.0, np.nan]])), format="csc")
    f = pb.PardisoLDL(U)
    f.factor(U)
    x = f.solve(np.ones(2))
    if f.inertia() is None:  # PARDISO refused it: NaN, no inertia
        assert np.isnan(x).all()
    else:  # it factorised NaN values: the direction is not finite either
        assert not np.isfinite(x).all()


@pytest.mark.parametrize("backend", ["qdldl", pytest.param("pardiso", marks=needs_pardiso)])
def test_a_matrix_factorised_last_is_not_factorised_again(backend, monkeypatch):
    """The verification right after a solve (the same exact Hessian at the same point) re-uses the factorisation:
    no new one, the same Verification (inertia, decrement) bit for bit; a changed matrix is factorised afresh."""
    shape = dop.shapes.load("bar")
    s = Solver(shape.mesh, shape.handles, "sarap", backend=backend)
    targets = shape.targets(shape.P_moving + np.array([[-0.05, 0.1]]))
    T, r = s.targets_of(targets), s.solve(targets)
    assert r.converged
    H = type(s.hessian)
    real, calls = H._factorise, []  # the back end's numeric factorisation, behind factorise's re-use
    monkeypatch.setattr(H, "_factorise", lambda self, K, b: calls.append(1) or real(self, K, b))
    first = s.verify(r.X, T)
    n_first = len(calls)
    again = s.verify(r.X, T)
    assert len(calls) == n_first  # the same K as the last factorised one
    fields = ("ok", "failed", "negative", "decrement", "energy")
    assert [getattr(again, f) for f in fields] == [getattr(first, f) for f in fields]
    moved = r.X.copy()
    moved[s.free_vertices[:3]] += 1e-6
    s.verify(moved, T)
    assert len(calls) == n_first + 1  # other values: factorised
    assert (s.verify(r.X, T).negative, len(calls)) == (first.negative, n_first + 2)
