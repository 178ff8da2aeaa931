"""The reference truth of held-out comparisons (defop.training.reference): the lowest verified minimum of a fixed
portfolio, replacing the rest-pose minimum only where lower by more than the tolerance and distinct.

The bistable case is lesson 08's: the bar pushed in by 0.3 on its axis, where the rest pose reaches the bent-down
minimum and a start on the bent-up branch a minimum 0.35% lower.
"""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.training import reference as rf
from defop.training import solves
from defop.variational.solver import Solver


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))


@pytest.fixture(scope="module")
def case():
    """The bar, Q = p + (-0.3, 0), and a start on each branch (solved with the handle 0.06 off the axis)."""
    bar = dop.shapes.load("bar")
    s = Solver(bar.mesh, bar.handles, "sarap")
    p = bar.P_moving[0]
    up, down = (s.solve(bar.targets(np.array([[p[0] - 0.3, p[1] + dy]]))).X for dy in (0.06, -0.06))
    Q = np.array([[[p[0] - 0.3, p[1]]]])
    return bar, Q, up, down


def constant(X):
    """A stand-in reference operator: the same prediction at every Q."""
    return lambda Q: np.repeat(X[None], len(Q), axis=0)


def truth(case, X0, **kw):
    bar, Q, *_ = case
    return rf.reference_truth(bar, Q, reference=constant(X0), coarse=False, n_jobs=1, progress=False, **kw)


def test_the_reference_keeps_the_lower_of_two_verified_minima(case):
    bar, Q, up, down = case
    R = truth(case, up)
    assert R.converged.all() and R.rest_converged.all()
    gap = (R.rest_energy[0] - R.energy[0]) / R.rest_energy[0]
    assert 1e-3 < gap < 1e-2  # the premise: the rest pose reaches the higher minimum (0.35% above)
    assert R.source.tolist() == [rf.SOURCES.index("operator")] and R.replaced.all() and not R.agree.any()
    assert np.abs(R.X[0] - R.X_rest[0]).max() > 0.1 * bar.mesh.bbox_diagonal  # another branch, not the same minimum
    X, ok = dop.training.solve_samples(bar, Q, n_jobs=1, progress=False)
    assert ok.all() and np.array_equal(R.X_rest, X)  # the rest-pose truth is held_out's solve, bit for bit
    same = truth(case, down)  # a start on the rest pose's own branch: the two truths are the same arrays
    assert same.source.tolist() == [0] and np.array_equal(same.X, same.X_rest)


def test_only_beyond_the_tolerance(case):
    gap = (lambda R: (R.rest_energy[0] - R.energy[0]) / R.rest_energy[0])(truth(case, case[2]))
    assert truth(case, case[2], tol=2 * gap).source.tolist() == [0]  # a smaller gap than tol: the rest pose
    assert truth(case, case[2], tol=gap / 2).source.tolist() == [2]
    # the rule itself, at the tolerance's edge: the two real minima with the lower one's energy set near the rest's
    bar, _, up, down = case
    diag, E = bar.mesh.bbox_diagonal, 0.0103
    for rel, want in ((5e-7, 1), (2e-6, 0), (0.0, 1)):
        assert rf.pick([(up, E * (1 - rel), True), (down, E, True)], diag) == want
    copy = (down + 1e-6 * diag, 0.9 * E, True)  # lower, but the rest pose's own minimum
    assert rf.pick([copy, (down, E, True)], diag) == 1
    assert rf.pick([copy, (up, 0.95 * E, True), (down, E, True)], diag) == 1  # the lower distinct minimum
    assert rf.pick([(up, 0.5 * E, False), (down, E, True)], diag) == 1  # an unverified end point never wins
    assert rf.pick([(up, E, True), (down, np.nan, False)], diag) == 0  # an unverified rest pose gives way


def test_stored_with_its_digest_and_reused(case, monkeypatch):
    first = truth(case, case[2])
    monkeypatch.setattr(solves, "solve", lambda *a, **k: pytest.fail("the cached reference was solved again"))
    again = truth(case, case[2])
    assert again.digest == first.digest and again.digest.startswith("reference-")
    for f in ("X", "X_rest", "energy", "rest_energy", "source", "converged"):
        assert np.array_equal(getattr(again, f), getattr(first, f))
    monkeypatch.undo()
    assert truth(case, case[3]).digest != first.digest  # another reference operator: another entry
    monkeypatch.setattr(rf, "RULE", rf.RULE + 1)  # a new pick rule or portfolio never reads the old entry
    assert truth(case, case[2]).digest != first.digest


def test_coarse_minima_join_the_portfolio(case):
    bar, Q, *_ = case
    p = bar.P_moving[0]
    Qs = np.concatenate([Q, p + np.array([[[-0.1, 0.05]], [[0.05, -0.1]], [[-0.2, 0.02]]])])
    starts, kinds = rf.portfolio_starts(bar, Qs, "sarap", n_jobs=1, progress=False)
    assert all(len(s) >= 1 and set(k) == {1} for s, k in zip(starts, kinds))  # >= 1 prolongated coarse minimum
    R = rf.reference_truth(bar, Qs, n_jobs=1, progress=False)
    assert R.converged.all() and set(R.source.tolist()) <= {0, 1}
    assert (R.energy <= R.rest_energy).all()


@pytest.mark.parametrize(
    "kw, match",
    [({"tol": -1.0}, "tol"), ({"tol": np.nan}, "tol"), ({"reference": 3}, "reference"), ({"energy": "x"}, "energy")],
)
def test_bad_input_is_named_before_any_solve(case, kw, match, monkeypatch):
    bar, Q, *_ = case
    monkeypatch.setattr(solves, "solve", lambda *a, **k: pytest.fail("solved before checking"))
    with pytest.raises(ValueError, match=match):
        rf.reference_truth(bar, Q, **kw)
    with pytest.raises(ValueError, match="Q"):
        rf.reference_truth(bar, Q[:, :, :1])
