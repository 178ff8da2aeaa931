"""A stranger's review of the engine / operator core / file-home change: each test fails on the code before its fix."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import defop as dop


def _one_deprecation(get):
    """The value of ``get()`` and its one DeprecationWarning (asserted to point at this file)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = get()
    assert [w.category for w in caught] == [DeprecationWarning], [str(w.message) for w in caught]
    assert caught[0].filename == __file__, caught[0].filename
    return value, str(caught[0].message)


@pytest.mark.parametrize(
    ("old", "new"), [("Branch", "SampledBranch"), ("Branches", "SampledBranches"), ("distinct_minima", "distinct_at")]
)
def test_renamed_branch_names_warn_at_the_callers_line(old, new):
    from defop.training import branches

    value, message = _one_deprecation(lambda: getattr(branches, old))
    assert value is getattr(branches, new) and new in message


@pytest.mark.parametrize("name", ["finish", "solve_best"])
def test_solver_module_functions_still_work_and_warn(name):
    from defop.variational import solver as sv

    call, message = _one_deprecation(lambda: getattr(sv, name))
    assert f"Solver.{name}" in message
    if name == "solve_best":
        bar = dop.shapes.load("bar")
        solver = sv.Solver(bar.mesh, bar.handles)
        old = call(solver, bar.targets(bar.P[bar.moving]))
        new = solver.solve_best(bar.targets(bar.P[bar.moving]))
        assert old.converged and np.array_equal(old.X, new.X)
