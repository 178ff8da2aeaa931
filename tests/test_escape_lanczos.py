"""The escape from a saddle when Lanczos (ARPACK) does not converge: a second attempt with a larger Krylov space,
and if that fails too the point stays a saddle (not converged) instead of crashing the solve."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from defop.variational import escape


class _Hessian:
    def __init__(self, K):
        self.K = K

    def full(self, data):
        return self.K


class _Solver:
    """The three things negative_curvature reads: grad_hess, hessian.full and full (free rows to a field)."""

    def __init__(self, K):
        self.hessian = _Hessian(K)

    def grad_hess(self, X, mu, project=True):
        return None, None, None

    def full(self, v):
        return v.reshape(-1, 2)


@pytest.fixture
def solver():
    n = 600  # above the dense threshold: Lanczos
    diag = np.linspace(1.0, 2.0, n)
    diag[137] = -0.5
    return _Solver(sp.diags(diag).tocsc())


def _stalling(real, fail_times):
    calls = {"n": 0}

    def eigsh(*args, **kw):
        calls["n"] += 1
        if calls["n"] <= fail_times:
            raise sla.ArpackNoConvergence("no convergence", np.empty(0), np.empty((args[0].shape[0], 0)))
        return real(*args, **kw)

    return eigsh, calls


def test_a_stalled_lanczos_is_retried_with_a_larger_krylov_space(solver, monkeypatch):
    eigsh, calls = _stalling(sla.eigsh, 1)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    lam, D = escape.negative_curvature(solver, None)
    assert calls["n"] == 2
    assert lam == pytest.approx(-0.5, abs=1e-8)
    assert abs(D.ravel()[137]) == pytest.approx(1.0, abs=1e-6)


def test_without_convergence_the_escape_has_no_direction_and_does_not_raise(solver, monkeypatch):
    eigsh, calls = _stalling(sla.eigsh, 2)
    monkeypatch.setattr(escape.sla, "eigsh", eigsh)
    with pytest.raises(sla.ArpackNoConvergence):
        escape.negative_curvature(solver, None)
    calls["n"] = 0
    assert escape.descent_direction(solver, None) is None
    assert calls["n"] == 2
