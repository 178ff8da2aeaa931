"""Option validation (defop.options) and the options of the trajectory ground truth."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop import options as opt
from defop.analysis import trajectories as tr


@pytest.mark.parametrize("value", [3, np.int64(3), 3.0, np.float32(3.0)])
def test_integer_accepts_integral_values(value):
    assert opt.integer("m", value, minimum=1) == 3 and type(opt.integer("m", value)) is int


@pytest.mark.parametrize("value", [2.5, True, np.bool_(True), "3", None, float("nan"), float("inf"), [3], 1 + 0j])
def test_integer_rejects_everything_else_by_name(value):
    with pytest.raises(ValueError, match=r"^count must be an integer, got "):
        opt.integer("count", value)


def test_integer_bounds_are_in_the_message():
    with pytest.raises(ValueError, match=r"^k must be an integer >= 1 and <= 10, got 11$"):
        opt.integer("k", 11, minimum=1, maximum=10)
    assert opt.integer("k", 10, minimum=1, maximum=10) == 10


def test_choice_lists_the_known_values():
    with pytest.raises(ValueError, match=r"^unknown colour 'mauve'; known: red, green$"):
        opt.choice("colour", "mauve", ("red", "green"))
    with pytest.raises(ValueError, match="unknown colour"):
        opt.choice("colour", ["red"], ("red", "green"))  # unhashable: still a ValueError


def test_n_jobs():
    assert opt.n_jobs(None) is None and opt.n_jobs(-1) == -1 and opt.n_jobs(2) == 2
    with pytest.raises(ValueError, match="n_jobs must be a non-zero integer"):
        opt.n_jobs(0)


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture
def no_solves(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("a solve ran before the options were checked")

    monkeypatch.setattr(dop.variational.Solver, "solve", fail)  # the primitive every driver calls


BAD_TRAJ_OPTIONS = [
    ({"moving": 0.5}, "moving must be an integer >= 0, got 0.5"),
    ({"moving": True}, "moving must be an integer >= 0, got True"),
    ({"moving": -1}, "moving must be an integer >= 0, got -1"),
    ({"moving": 1}, r"moving handle index 1 out of range \[0, 1\)"),
    ({"energy": "spring"}, "unknown energy 'spring'"),
    ({"n_jobs": 0}, "n_jobs must be a non-zero integer"),
    ({"mode": "both"}, "mode must be 'global' or 'local'"),
]


@pytest.mark.parametrize(("options", "message"), BAD_TRAJ_OPTIONS, ids=[str(o) for o, _ in BAD_TRAJ_OPTIONS])
def test_ground_truth_trajectories_reject_bad_options_by_name(bar, options, message, no_solves):
    g = tr.handle_grid(bar.P_moving[0], 0.05, 2)
    with pytest.raises(ValueError, match=message):
        tr.ground_truth_trajectories(bar, g, **({"n_jobs": 1, "cache": False} | options))


def test_ground_truth_trajectories_need_a_handle_grid(bar, no_solves):
    with pytest.raises(ValueError, match="grid must be a HandleGrid .* got ndarray"):
        tr.ground_truth_trajectories(bar, np.zeros((3, 3, 2)), cache=False)


@pytest.mark.parametrize(
    "value, what",
    [
        ([[1 + 2j, 0.0]], "complex numbers"),
        ([[True, False]], "booleans"),
        ("ab", "strings"),
        ([[0.0, 1.0], [2.0]], "a ragged sequence"),
        ([object()], "Python objects"),
    ],
)
def test_real_array_rejects_what_a_float_cast_would_mangle(value, what):
    with pytest.raises(ValueError, match=f"Q must be an array of real numbers, got {what}"):
        opt.real_array("Q", value)


def test_real_array_passes_ints_and_floats():
    a = opt.real_array("Q", [[1, 2], [3, 4]])
    assert a.dtype == float and a.tolist() == [[1.0, 2.0], [3.0, 4.0]]


def test_complex_targets_and_start_are_rejected_not_truncated():
    """np.asarray(..., dtype=float) dropped the imaginary part with only a ComplexWarning."""
    bar = dop.shapes.load("bar")
    T = bar.mesh.V[[0, 5]] + 0.1
    with pytest.raises(ValueError, match="targets must be an array of real numbers, got complex numbers"):
        dop.solve(bar.mesh, [0, 5], T + 1e-3j)
    with pytest.raises(ValueError, match="X0 must be an array of real numbers, got complex numbers"):
        dop.solve(bar.mesh, [0, 5], T, X0=bar.mesh.V + 0j)


@pytest.mark.parametrize("value", [0, -1.5, np.nan, np.inf, True, "1", None, 1j])
def test_positive_rejects_everything_else_by_name(value):
    with pytest.raises(ValueError, match=r"size must be a positive number, got"):
        opt.positive("size", value)


def test_positive_accepts_finite_positive_reals():
    assert opt.positive("size", 2) == 2.0 and opt.positive("size", np.float32(0.5)) == 0.5


def test_from_image_refuses_a_negative_size():
    """size = -1 was accepted: the silhouette was scaled by a negative factor (mirrored through the origin)."""
    img = np.zeros((40, 60))
    img[10:30, 10:50] = 1
    with pytest.raises(ValueError, match="size must be a positive number, got -1"):
        dop.shapes.from_image(img, size=-1)
