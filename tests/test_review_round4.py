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


@pytest.fixture(scope="module")
def bar_op(tmp_path_factory):
    import os

    os.environ.setdefault("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return dop.train(dop.shapes.load("bar"), m=10, rounds=1, n_jobs=1, progress=False)[0]


@pytest.mark.parametrize(
    ("Qs", "what"), [([[["a", "b"]]], "strings"), ([[[True, False]]], "booleans"), ([[[None, 1.0]]], "Python objects")]
)
def test_evaluate_batch_names_qs_for_input_that_is_not_real(bar_op, Qs, what):
    with pytest.raises(ValueError, match=f"Qs must be an array of real numbers, got {what}"):
        bar_op.evaluate_batch(np.array(Qs))


@pytest.mark.parametrize("name", ["operator-3_tps_rank3.npz", "movable-1.npz", "branched-2.npz"])
def test_mesh_load_names_an_operator_file(name):
    """The operator loaders name a mesh file; Mesh.load said "moving must hold numbers" of an operator file."""
    from pathlib import Path

    path = Path(__file__).parent / "data" / "files" / name
    with pytest.raises(ValueError, match=f"{name} is a defop operator file, not a mesh file: load it with DefOp.load"):
        dop.Mesh.load(path)


@pytest.fixture(scope="module")
def bar_samples():
    bar = dop.shapes.load("bar")
    return bar, bar.P[bar.moving][None] + np.array([[[0.05, 0.0]], [[0.0, 0.05]], [[0.02, 0.02]]])


@pytest.mark.parametrize("cast", [lambda S: S + 0j, lambda S: S.astype(str), lambda S: np.ones(S.shape, bool)])
def test_engine_refuses_samples_that_are_not_real(bar_samples, cast):
    """complex samples lost their imaginary part (a ComplexWarning), strings and booleans were cast."""
    from defop.training import solves

    bar, S = bar_samples
    with pytest.raises(ValueError, match="samples must be an array of real numbers"):
        solves.solve(bar, cast(S), n_jobs=1, progress=False)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (lambda H: H[:2], r"handles must have shape \(3, 4\)"),  # zip() dropped the third sample
        (lambda H: H[:, :1], r"handles must have shape \(3, 4\)"),
        (lambda H: H + 0.5, "integer vertex indices"),
        (lambda H: H + 10**6, r"vertex indices in \[0, 596\)"),
    ],
)
def test_engine_checks_handles_per_sample(bar_samples, bad, match):
    from defop.training import solves

    bar, S = bar_samples
    H = np.tile(bar.handles, (len(S), 1))
    with pytest.raises(ValueError, match=match):
        solves.solve(bar, S, handles=bad(H), n_jobs=1, progress=False)


@pytest.mark.parametrize("method", ["exists", "estimates", "__call__"])
@pytest.mark.parametrize(("cast", "what"), [(lambda Q: Q.astype(str), "strings"), (lambda Q: Q > 0, "booleans")])
def test_branched_operator_checks_q_once_on_every_path(method, cast, what):
    """exists/estimates cast strings and booleans to numbers; __call__ warned of extrapolation before refusing."""
    from pathlib import Path

    from defop.operator.branched import BranchedOperator

    op = BranchedOperator.load(Path(__file__).parent / "data" / "files" / "branched-2.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=f"Q must be an array of real numbers, got {what}"):
            getattr(op, method)(cast(op.P + 0.01))


@pytest.mark.parametrize(
    ("samples", "sweep", "match"),
    [
        (None, [0.0, 1.2, 2.9, 3.0], "sweep 0 must be a permutation"),  # truncated to 0, 1, 2, 3 and used
        (None, [True, False, True, True], "sweep 0 must be a permutation"),
        ("complex", [0, 1, 2, 3], "samples must be an array of real numbers"),  # the imaginary part was dropped
    ],
)
def test_discover_refuses_fractional_sweeps_and_complex_samples(samples, sweep, match):
    from defop.training import branches as br

    bar = dop.shapes.load("bar")
    Q = br.grid_samples(bar, 0.1, 2)
    Q = Q + 0j if samples == "complex" else Q
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=match):
            br.discover(bar, Q, [sweep], cache=False)


def test_movable_sampling_names_m_and_rng(movable_rect):
    """sample_placements(m=-1) raised numpy's 'negative dimensions'; a bad rng, SeedSequence's TypeError."""
    from defop.scene.placement import placement_regions
    from defop.training.movable import sample_joint, sample_placements

    rect = movable_rect(120)  # tests/conftest.py
    placement = placement_regions(rect, [0, 1], radius=0.15)
    with pytest.raises(ValueError, match="m must be an integer >= 1, got -1"):
        sample_placements(placement, -1, 0)
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator or a seed"):
        sample_joint(rect, placement, 2, "x")
    a, b = sample_joint(rect, placement, 3, 5), sample_joint(rect, placement, 3, np.random.default_rng(5))
    assert all(np.array_equal(x, y) for x, y in zip(a, b))  # a seed and its generator: the same samples


@pytest.mark.parametrize(
    ("ext", "text", "where"),
    [
        (".obj", "v 1_0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "OBJ line 1, coordinate 0"),
        (".off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1_5 0\n3 0 1 2\n", "OFF line 5"),
        (
            ".stl",
            "solid t\nfacet normal 0 0 0\nouter loop\nvertex 0 0 0\nvertex 1_0 0 0\nvertex 0 1 0\nendloop\n"
            "endfacet\nendsolid t\n",
            "ASCII STL facet 0, coordinate 3",
        ),
    ],
)
def test_a_digit_separator_is_not_a_number_in_surface_files(tmp_path, ext, text, where):
    """Python's float() read '1_0' as 10: a coordinate no surface format writes, silently taken as another number."""
    from defop.geometry.surface_files import read_surface_file

    path = tmp_path / f"s{ext}"
    path.write_text(text)
    with pytest.raises(ValueError, match=f"{where}.*is not a number"):
        read_surface_file(path)


def test_fast_state_and_kernel_state_keep_their_mapping_access(bar_op):
    """fast_matrices returned a dict and kernel_state a dict of the kernel's arguments; both became dataclasses,
    so f["mats"] and state["A"] raised TypeError ('not subscriptable'), the deprecated name included."""
    from defop.operator import defop as od

    f = od.fast_matrices(bar_op.handle_basis, bar_op.WF)
    assert f["mats"] is f.mats and f["R2"] == f.R2 and f["key"] is None
    state, _ = _one_deprecation(lambda: od.kernel_state(bar_op.handle_basis, f.mats))
    args = od.core.kernel_args(bar_op.handle_basis, f.mats)
    assert len(state["tps"]) == len(args.tps) and state["tps"][-1] == args.tps[-1]
    for key in ("A", "B", "far2"):
        assert np.array_equal(state[key], getattr(args, key)), key
    assert state["apply"] is args.lib.frame_from_raw and state["beyond"] is args.lib.beyond_bound
    assert state["tps_frame"] is args.lib.tps_frame


@pytest.mark.parametrize(
    "statement",
    [
        "from defop.variational import solve_lbfgs",  # a package: importlib's hasattr read it once more
        "from defop.training.branches import Branch",
        "from defop.training.multilevel import Levels",
    ],
)
def test_from_import_of_an_old_name_warns_once_at_the_import(statement):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        exec(compile(statement, "user_script.py", "exec"), {})
    assert [(w.category, w.filename) for w in caught] == [(DeprecationWarning, "user_script.py")]


@pytest.mark.parametrize(
    ("old", "new", "name"),
    [
        ("defop.analysis.peers", "defop.rivals.peers", "Peer"),
        ("defop.geometry.multilevel", "defop.geometry.coarse", "prolongate"),
        ("defop.analysis.figure_data", "defop.training.sampling", "patch_motions"),
    ],
)
def test_star_import_of_a_moved_module_binds_its_names(old, new, name):
    """A moved module had no __all__ and its names live in __getattr__: ``import *`` bound nothing."""
    import importlib

    namespace = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        exec(compile(f"from {old} import *", "user_script.py", "exec"), namespace)
    assert namespace.get(name) is getattr(importlib.import_module(new), name)
    assert caught and {(w.category, w.filename) for w in caught} == {(DeprecationWarning, "user_script.py")}


def test_every_public_name_of_the_moved_operator_modules_is_still_there():
    """operator.movable exported EXTRAPOLATION_FACTOR (imported from operator.defop); the core split dropped it."""
    from defop.operator import core, movable

    assert movable.EXTRAPOLATION_FACTOR == core.EXTRAPOLATION_FACTOR == 1.5


@pytest.mark.parametrize("moving", [0.5, True, "0", None])
def test_defop_trajectories_names_a_moving_index_that_is_not_an_integer(moving):
    """moving=0.5 passed the range check and raised numpy's IndexError; True was read as handle 1."""
    from pathlib import Path

    from defop.analysis import trajectories as tr
    from defop.operator.defop import DefOp

    op = DefOp.load(Path(__file__).parent / "data" / "files" / "operator-3_tps_rank3.npz")
    with pytest.raises(ValueError, match="moving handle index .* out of range"):
        tr.defop_trajectories(op, tr.handle_grid(op.P[0], 0.1, 3), moving=moving)
