"""The layout of defop.variational: one job per module, a Solver that holds its problem, old paths that warn."""

from __future__ import annotations

import ast
import importlib
import warnings
from pathlib import Path

import numpy as np
import pytest

import defop as dop
from defop.training import cache as cache_mod
from defop.variational import Solver, escape, solver
from defop.variational.problem import ReducedProblem

PACKAGE = Path(dop.__file__).parent / "variational"


def test_the_solver_holds_its_problem_instead_of_being_one():
    s = dop.shapes.load("bar", 200)
    sv = Solver(s.mesh, s.handles, "sarap")
    assert not issubclass(Solver, ReducedProblem)
    assert isinstance(sv.problem, ReducedProblem)
    assert sv.mesh is sv.problem.mesh and sv.hessian is sv.problem.hessian and sv.dim == 2
    assert np.array_equal(sv.free, sv.problem.free)
    sv.kernel = "numpy"
    assert sv.problem.kernel == "numpy" and sv.problem.elements.kernel == "numpy"
    with pytest.raises(AttributeError):
        sv.mesh = None


def test_finish_and_solve_best_exist_once():
    """Methods of Solver, not also module functions taking a solver (the old module names only warn and call them)."""
    assert "finish" not in vars(solver) and "solve_best" not in vars(solver)
    assert callable(Solver.finish) and callable(Solver.solve_best)


def test_the_solver_settings_keep_their_keys():
    """The cache keys read the solver's plain public attributes: the composition must not change them."""
    s = dop.shapes.load("bar", 200)
    got = cache_mod.solver_settings(Solver(s.mesh, s.handles, "sarap"))
    assert got == {
        "barrier": True,
        "class": "Solver",
        "energy": "sarap",
        "exact_switch": 0.01,
        "max_escapes": 4,
        "max_iter": 300,
        "mu_schedule": (1e-05, 0.0),
        "stage_tol": 1e-08,
        "tol": 1e-09,
        "verify_tol": 1e-06,
    }


@pytest.mark.parametrize("name", ["escape", "negative_curvature"])
def test_the_old_saddle_module_warns_and_works(name):
    old = importlib.import_module("defop.variational.saddle")
    with pytest.warns(DeprecationWarning, match=f"defop.variational.escape.{name}"):
        assert getattr(old, name) is getattr(escape, name)
    with pytest.raises(AttributeError):
        old.no_such_name  # noqa: B018


@pytest.mark.parametrize(
    "module,names",
    [
        ("problem", ["choose_backend", "HAVE_PARDISO", "PardisoLDL", "check_handles", "check_targets", "count_flips"]),
        ("volumetric", ["signed_svd", "svd_frame", "max_flip_free_step", "STEP_SCREEN"]),
        ("fused", ["flip_free_step2", "grad_hess", "energies", "scatter", "slot_map", "vertex_order"]),
    ],
)
def test_split_modules_keep_exporting_their_public_names(module, names):
    mod = importlib.import_module(f"defop.variational.{module}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in names:
            assert getattr(mod, name) is not None


def test_no_module_is_over_500_lines():
    sizes = {p.name: len(p.read_text().splitlines()) for p in PACKAGE.glob("*.py")}
    assert {k: n for k, n in sizes.items() if n > 500} == {}


def test_no_private_name_is_imported_across_modules():
    """``from .x import _y`` (or ``from defop.variational.x import _y``) anywhere in defop: none."""
    bad = []
    root = Path(dop.__file__).parent
    for path in root.rglob("*.py"):
        inside = path.parent == PACKAGE
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (inside or "variational" in (node.module or "")):
                bad += [f"{path.name}:{node.lineno} {a.name}" for a in node.names if a.name.startswith("_")]
    assert bad == []
