"""The editor's state under random sequences of valid and invalid calls (issue 26): a rejected call changes nothing.

Every setter of :class:`defop.editor.state.EditorState` validates first and commits last; what can still fail
after validation (an operator that returns NaN, a ground-truth solver that raises) is undone. The invariants
are checked after every call: Q finite and of the moving handles' shape, X = D(·, Q) of the current basis,
the handles of X at Q (Prop. 2), ``flipped`` the triangles X flips, ``active`` a handle or None. The browser
editor's synced traits (what the page holds) must equal the state after every call, accepted or not.
"""

from __future__ import annotations

import types
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.editor.state import EditorState

STATE = (
    "Q",
    "X",
    "flipped",
    "eval_time",
    "kind",
    "gt_enabled",
    "X_gt",
    "Q_gt",
    "gt_result",
    "gt_error",
    "gt_time",
    "active",
)


class Faulty:
    """A real DefOp that returns NaN when handle 0 is above y = 0.15: an evaluation that fails after validation."""

    def __init__(self, op):
        self._op = op

    def __getattr__(self, name):
        return getattr(self._op, name)

    def __call__(self, Q):
        X = self._op(Q)
        return X * np.nan if np.asarray(Q)[..., 0, 1].max() > 0.15 else X


class Solver:
    """A ground-truth solver that raises when the moving handle is below y = -0.2 (after the state validated Q)."""

    def __init__(self, moving):
        self.moving = moving

    def solve_best(self, targets, starts, rest=True, keep="first"):
        if targets[self.moving][0, 1] < -0.2 or not np.isfinite(targets).all():
            raise RuntimeError("the solver failed")
        return types.SimpleNamespace(X=np.asarray(starts[-1]) + 1e-3, converged=True)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    shape = dop.shapes.load("bar", n_vertices=150)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tps, _ = dop.train(shape, basis="tps", m=12, seed=0, progress=False, n_jobs=1)
        linear, _ = dop.train(shape, basis="linear", m=12, seed=0, progress=False, n_jobs=1)
    yield shape, {"tps": tps, "linear": Faulty(linear)}
    mp.undo()


def _state(setup):
    shape, ops = setup
    return EditorState(shape, dict(ops), basis="tps", kinds=("tps", "linear"), solver=Solver(shape.moving))


def _snapshot(s):
    return {
        name: (np.array(v, copy=True) if isinstance(v, np.ndarray) else v) for name in STATE for v in [getattr(s, name)]
    }


def _same(a, b):
    for name in STATE:
        x, y = a[name], b[name]
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and np.array_equal(x, y), name
        else:
            assert x is y or x == y, name


def _invariants(s):
    assert s.Q.shape == s.P.shape and np.isfinite(s.Q).all()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        X = s.operator(s.Q)
    np.testing.assert_array_equal(s.X, X)  # X = D(·, Q) of the current basis
    moving = s.shape.handles[s.shape.moving]
    np.testing.assert_allclose(s.X[moving], s.Q, atol=1e-9 * s.diag)  # Prop. 2: the handles are at Q
    np.testing.assert_array_equal(s.flipped, s.mesh.flipped(s.X))
    assert s.active is None or 0 <= s.active < len(s.P)
    if s.gt_enabled:
        assert s.X_gt is not None and np.array_equal(s.Q_gt, s.Q)


coord = st.floats(-0.5, 1.5)
bad_scalar = st.sampled_from([np.nan, np.inf, -np.inf, "1", None, 1j, [1.0, 2.0]])
point = st.tuples(coord, coord).map(list)
bad_point = st.one_of(
    coord, st.sampled_from([[np.nan, 0.0], [0.0, np.inf], [1.0, 2.0, 3.0], "xy", [1j, 0], [[0.5, 0]], None, []])
)
Q_valid = st.tuples(coord, coord).map(lambda p: np.array([p]))
Q_bad = st.one_of(
    coord,
    st.sampled_from(
        [
            np.zeros((2, 2)),
            np.zeros(2),
            np.full((1, 2), np.nan),
            "Q",
            np.ones((1, 2)) * 1j,
            [[0.5, 0.1, 0]],
            [[[0.5, 0.1]]],
        ]
    ),
)
index_bad = st.sampled_from([1, -1, 0.5, "0", None, np.nan, True])

call = st.one_of(
    st.tuples(st.just("set_Q"), st.one_of(Q_valid, Q_bad).map(lambda q: (q,))),
    st.tuples(st.just("set_handle"), st.tuples(st.one_of(st.just(0), index_bad), st.one_of(point, bad_point))),
    st.tuples(st.just("press"), st.tuples(st.one_of(coord, bad_scalar), st.one_of(coord, bad_scalar))),
    st.tuples(st.just("drag"), st.tuples(st.one_of(coord, bad_scalar), coord)),
    st.tuples(
        st.just("release"),
        st.one_of(st.just(()), st.tuples(coord, coord), st.tuples(coord, st.none()), st.tuples(bad_scalar, coord)),
    ),
    st.tuples(st.just("set_basis"), st.sampled_from(["tps", "linear", "cubic", "", None, 3]).map(lambda k: (k,))),
    st.tuples(
        st.just("set_ground_truth"), st.sampled_from([True, False, "off", 2, None, np.bool_(True)]).map(lambda v: (v,))
    ),
    st.tuples(st.just("reset"), st.just(())),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(calls=st.lists(call, min_size=1, max_size=12))
def test_random_calls_keep_the_invariants_and_a_rejected_call_changes_nothing(setup, calls):
    s = _state(setup)
    for method, args in calls:
        before = _snapshot(s)
        try:
            getattr(s, method)(*args)
        except (ValueError, RuntimeError) as exc:
            # ValueError: validation; RuntimeError: the fake solver, after validation; both leave no trace
            assert str(exc)
            _same(before, _snapshot(s))
        _invariants(s)


@pytest.mark.parametrize("q", [0.5, np.float64(0.5), [0.5], [[0.5, 0.5]], [0.5, 0.5, 0.5]])
def test_a_scalar_is_not_broadcast_to_a_point(setup, q):
    s = _state(setup)
    before = _snapshot(s)
    with pytest.raises(ValueError, match=r"^q must be a point of 2 coordinates, got "):
        s.set_handle(0, q)
    _same(before, _snapshot(s))


def test_an_evaluation_that_fails_after_validation_leaves_the_state(setup):
    s = _state(setup)
    s.set_basis("linear")
    before = _snapshot(s)
    with pytest.raises(ValueError, match="invalid deformation"):
        s.set_handle(0, s.P[0] + [0.0, 0.2])  # the faulty operator returns NaN there
    _same(before, _snapshot(s))
    with pytest.raises(ValueError, match="invalid deformation"):
        s.set_Q(s.P + [0.0, 0.2])
    _same(before, _snapshot(s))


def test_a_failed_ground_truth_leaves_q_where_it_was(setup):
    s = _state(setup)
    s.set_ground_truth(True)
    before = _snapshot(s)
    with pytest.raises(RuntimeError, match="the solver failed"):
        s.set_handle(0, [0.95, -0.3])
    _same(before, _snapshot(s))
    assert s.gt_enabled and np.array_equal(s.Q_gt, s.Q)


@pytest.mark.parametrize("value", ["off", "", 2, None, 0.5])
def test_the_ground_truth_switch_takes_only_true_or_false(setup, value):
    s = _state(setup)
    with pytest.raises(ValueError, match=r"^enabled must be True or False, got "):
        s.set_ground_truth(value)
    assert not s.gt_enabled


# ------------------------------------------------------------------------------------------------ the page
trait_set = st.one_of(
    st.tuples(
        st.just("q"),
        st.one_of(point, st.sampled_from([[0.1], [0.1, 0.2, 0.3], [], ["a", "b"], [np.nan, 0.0], [0.95, -0.3]])),
    ),
    st.tuples(st.just("basis"), st.sampled_from(["tps", "linear", "quartic", ""])),
    st.tuples(st.just("shape_name"), st.sampled_from(["bar", "nope"])),
    st.tuples(st.just("ground_truth"), st.booleans()),
)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(sets=st.lists(trait_set, min_size=1, max_size=8))
def test_the_page_traits_and_the_state_never_disagree(setup, sets):
    pytest.importorskip("anywidget")
    from defop.editor.browser import BrowserEditor

    shape, ops = setup
    editor = BrowserEditor(shape, {"tps": ops["tps"]}, kinds=("tps",), solver=Solver(shape.moving))
    for name, value in sets:
        before = _snapshot(editor.state)
        try:
            setattr(editor, name, value)
        except (ValueError, RuntimeError):
            _same(before, _snapshot(editor.state))
        s = editor.state
        assert editor.q == s.Q.ravel().tolist()  # what the page was sent is what the state holds
        assert editor.basis == s.kind and editor.shape_name == s.shape.name
        assert editor.ground_truth == s.gt_enabled
        _invariants(s)


def test_wrong_length_handles_from_the_page_are_undone_in_the_page(setup):
    pytest.importorskip("anywidget")
    from defop.editor.browser import BrowserEditor

    shape, ops = setup
    editor = BrowserEditor(shape, {"tps": ops["tps"]}, kinds=("tps",))
    q0 = editor.q
    with pytest.raises(ValueError, match=r"^q must be a flat list of 2 coordinates"):
        editor.q = [0.1, 0.2, 0.3]
    assert editor.q == q0 == editor.state.Q.ravel().tolist()
    with pytest.raises(ValueError, match=r"^Q must have shape \(1, 2\)"):
        editor.set_Q(np.zeros((2, 2)))
    assert editor.q == q0 == editor.state.Q.ravel().tolist()


def test_a_control_the_state_rejects_shows_the_state_again(setup):
    from defop.editor.widgets import Controls

    s = _state(setup)
    s.set_handle(0, s.P[0] + [0.0, 0.1])  # the faulty linear operator returns NaN here
    controls = Controls(s)
    before = _snapshot(s)
    with pytest.raises(ValueError, match="invalid deformation"):
        controls.basis.value = "linear"
    assert controls.basis.value == "tps" == s.kind
    _same(before, _snapshot(s))


def test_the_browser_editor_checks_the_shape_menu_first(setup):
    pytest.importorskip("anywidget")
    from defop.editor.browser import BrowserEditor

    shape, ops = setup
    with pytest.raises(ValueError, match=r"^shapes must be names of built-in shapes \(bar, .*\), got 'nope'"):
        BrowserEditor(shape, {"tps": ops["tps"]}, kinds=("tps",), shapes=["bar", "nope"])
