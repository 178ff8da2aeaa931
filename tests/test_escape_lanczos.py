"""The most negative curvature of the reduced Hessian above the dense threshold: shift-invert Lanczos (ARPACK) on
the solver's own LDLᵀ of K + s I, the same eigenpair as ``numpy.linalg.eigh``'s lowest; plain Lanczos when it
does not converge, a second attempt with a larger Krylov space, and if that fails too the point stays a saddle (not
converged) instead of crashing the solve."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as sla
from threadpoolctl import threadpool_limits

import defop as dop
from defop.variational import escape
from defop.variational.solver import Solver


class _Shifted:
    """The bar's solver with its exact reduced Hessian at rest lowered by c on the diagonal: q negative
    eigenvalues where c lies between the q-th and (q+1)-th eigenvalue of the Hessian at rest."""

    def __init__(self, solver, data):
        self.solver, self.data, self.hessian = solver, data, solver.hessian

    def grad_hess(self, X, mu, project=True):
        return None, None, self.data

    def full(self, v):
        return self.solver.full(v)


@pytest.fixture(scope="module")
def bar():
    shape = dop.shapes.load("bar")
    S = Solver(shape.mesh, shape.handles, "sarap")
    data = S.grad_hess(shape.mesh.V, 0.0, project=False)[2]
    lam = np.linalg.eigvalsh(S.hessian.full(data).toarray())
    assert S.hessian.nf > escape.DENSE_MAX  # the sparse path
    return S, data, lam


def _lowered(bar, q):
    S, data, lam = bar
    data = data.copy()
    data[S.hessian.diag] -= (lam[q - 1] + lam[q]) / 2
    return _Shifted(S, data)


@pytest.mark.parametrize("q", [1, 3])
def test_the_shift_invert_eigenpair_is_eighs_lowest(bar, q):
    solver = _lowered(bar, q)
    with threadpool_limits(limits=1):  # as negative_curvature runs it: the dense path is then the same bits
        lam, v = np.linalg.eigh(solver.hessian.full(solver.data).toarray())
    assert np.sum(lam < 0) == q
    got, D = escape.negative_curvature(solver, None)
    assert got == pytest.approx(lam[0], rel=1e-9, abs=1e-12)
    d = D.ravel()[bar[0].free]
    assert abs(d @ v[:, 0]) == pytest.approx(1.0, abs=1e-9)  # the same vector up to its sign
    assert d @ escape._sign_probe(len(d)) > 0  # the sign convention: positive along the fixed probe
    assert np.all(D[bar[0].handles] == 0)
    dense, Dd = escape.negative_curvature(solver, None, dense_max=10**6)  # numpy's eigh, the small-K path
    sign = np.sign(v[:, 0] @ escape._sign_probe(len(d)))  # the same convention on the dense path
    assert dense == lam[0] and np.array_equal(Dd.ravel()[bar[0].free], sign * v[:, 0])


def test_more_than_q_max_below_the_shift_takes_plain_lanczos(bar, monkeypatch):
    """Shift-invert would need k = q Lanczos vectors and more; above Q_MAX the plain iteration (k = 1) runs."""
    q = escape.Q_MAX + 1
    solver = _lowered(bar, q)
    lam = np.linalg.eigvalsh(solver.hessian.full(solver.data).toarray())
    assert np.sum(lam < 0) == q
    eigsh, calls = _stalling(sla.eigsh, 0)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    got, _ = escape.negative_curvature(solver, None)
    assert calls["sigma"] == [None] and got == pytest.approx(lam[0], rel=1e-5)


def _stalling(real, fail_times):
    calls = {"n": 0, "sigma": []}

    def eigsh(*args, **kw):
        calls["n"] += 1
        calls["sigma"].append(kw.get("sigma"))
        if calls["n"] <= fail_times:
            raise sla.ArpackNoConvergence("no convergence", np.empty(0), np.empty((args[0].shape[0], 0)))
        return real(*args, **kw)

    return eigsh, calls


def test_a_stalled_shift_invert_falls_back_to_plain_lanczos_then_a_larger_krylov_space(bar, monkeypatch):
    solver = _lowered(bar, 1)
    exact, _ = escape.negative_curvature(solver, None)
    eigsh, calls = _stalling(sla.eigsh, 2)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    lam, D = escape.negative_curvature(solver, None)
    assert calls["n"] == 3 and calls["sigma"][0] is not None and calls["sigma"][1:] == [None, None]
    assert lam == pytest.approx(exact, rel=1e-6)
    assert np.linalg.norm(D) == pytest.approx(1.0)


def test_without_convergence_the_escape_has_no_direction_and_does_not_raise(bar, monkeypatch):
    solver = _lowered(bar, 1)
    eigsh, calls = _stalling(sla.eigsh, 3)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    with pytest.raises(sla.ArpackNoConvergence):
        escape.negative_curvature(solver, None)
    calls["n"] = 0
    assert escape.descent_direction(solver, None) is None
    assert calls["n"] == 3


def test_nothing_below_the_shift_takes_plain_lanczos(bar, monkeypatch):
    """A Hessian with no eigenvalue below check 5's −s (q = 0 in K + s I's inertia): plain Lanczos, no σ."""
    S, data, lam = bar
    solver = _Shifted(S, data)  # positive definite
    eigsh, calls = _stalling(sla.eigsh, 0)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    got, _ = escape.negative_curvature(solver, None)
    assert calls["sigma"] == [None] and got == pytest.approx(lam[0], rel=1e-5)
