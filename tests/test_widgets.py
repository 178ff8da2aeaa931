"""The editor's state driven through its public API, and the matplotlib / ipywidgets views that show it (Agg).

The operators are real DefOps trained with few samples on a coarse bar (cached in a temporary
DEFOP_CACHE), so the checks exercise the actual evaluation path: the interpolation property
(handles map exactly to Q, Prop. 2), the rest pose D(·, P) = x (8b), and bases that differ.
Views are checked through what a user sees (the PNG, the readouts, the control values), not their artists.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import io

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from matplotlib.backend_bases import MouseEvent
from PIL import Image

import defop as dop
from defop.editor.state import EditorState, readout_text

M_TRAIN = 12  # samples per operator: enough for the linear basis (1 + 2n functions) on the bar


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A coarse bar and its trained linear and TPS DefOps (trained once per module)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    mp.setenv("DEFOP_N_JOBS", "1")
    shape = dop.shapes.load("bar", n_vertices=150)
    operators = {}
    for kind in ("linear", "tps"):
        operators[kind], _record = dop.train(shape, basis=kind, m=M_TRAIN, seed=0, progress=False, n_jobs=1)
    yield shape, operators
    mp.undo()


@pytest.fixture
def state(setup):
    shape, operators = setup
    return EditorState(shape, dict(operators), basis="tps", kinds=("linear", "tps"))


@pytest.fixture
def editor(state):
    ed = dop.editor.widgets.HandleEditor(state)
    yield ed
    ed.close()


def _offset(s):
    """A displacement of 15% of the diagonal, up and to the right (inside the axes)."""
    return np.array([0.15, 0.10]) * s.diag


def _drag(s, i, target, steps=6):
    start = s.Q[i].copy()
    assert s.press(*start) == i
    for t in np.linspace(0.0, 1.0, steps):
        assert s.drag(*(start + t * (target - start)))
    assert s.release()


def _png(data):
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.int16)


def test_rest_pose_at_start(state):
    np.testing.assert_allclose(state.Q, state.shape.P_moving)
    np.testing.assert_allclose(state.X, state.mesh.V, atol=1e-8)  # (8b): D(·, P) = x
    assert state.active is None and not state.flipped.any()


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(dx=st.floats(-0.3, 0.3), dy=st.floats(-0.3, 0.3), kind=st.sampled_from(["linear", "tps"]))
def test_drag_moves_handle_and_mesh_and_interpolates(state, dx, dy, kind):
    state.reset()
    state.set_basis(kind)
    V = state.mesh.V
    target = state.Q[0] + np.array([dx, dy]) * state.diag
    _drag(state, 0, target)
    np.testing.assert_allclose(state.Q[0], target)
    assert state.active is None
    np.testing.assert_allclose(state.X[state.shape.moving_handles], state.Q, atol=1e-8)  # Prop. 2
    fixed = state.shape.fixed_handles
    np.testing.assert_allclose(state.X[fixed], V[fixed], atol=1e-8)
    if np.hypot(dx, dy) > 0.05:
        assert np.abs(state.X - V).max() > 0.04 * state.diag  # the mesh moved
    assert state.eval_time > 0 and "evaluation" in readout_text(state)


def test_press_away_from_handles_picks_nothing(state):
    far = state.Q[0] + np.array([0.0, 3 * state.pick_radius * state.diag])
    assert state.press(*far) is None
    assert not state.drag(*(far + 0.1))
    assert not state.release()
    np.testing.assert_allclose(state.Q, state.P)


def test_readout_warns_when_a_handle_leaves_its_region(state):
    state.set_handle(0, state.P[0] + [3 * state.diag, 0.0])
    assert state.outside_regions() == [0]
    assert "beyond 1.5x its farthest training sample" in readout_text(state)


def test_switching_basis_changes_the_operator(state):
    Q = state.P + _offset(state)
    state.set_Q(Q)
    X_tps = state.X.copy()
    state.set_basis("linear")
    assert state.kind == "linear" and state.operator is state.operators["linear"]
    assert np.abs(state.X - X_tps).max() > 1e-4 * state.diag  # same Q, different DefOp
    np.testing.assert_allclose(state.X[state.shape.moving_handles], Q, atol=1e-8)
    state.set_basis("tps")
    np.testing.assert_allclose(state.X, X_tps)
    with pytest.raises(ValueError, match="not offered"):
        state.set_basis("quartic")


def test_bad_input_is_rejected(state, setup):
    with pytest.raises(ValueError, match="shape"):
        state.set_Q(np.zeros((state.shape.n_moving + 1, 2)))
    Q = state.P.copy()
    Q[0, 0] = np.nan
    with pytest.raises(ValueError, match="handle 0"):
        state.set_Q(Q)
    with pytest.raises(ValueError, match="out of range"):
        state.set_handle(state.shape.n_moving, (0.0, 0.0))
    with pytest.raises(ValueError, match="basis"):
        EditorState(setup[0], operators=setup[1], basis="spline")


def test_ground_truth_is_solved_on_release_only(state):
    """Slowest part (a few S-ARAP solves on ~150 vertices): one warm solve per release, none per drag frame,
    through the one warm-start policy (Solver.solve_best, keep="first") starting from the moved ground truth."""
    calls = []
    solver = state.solver
    original = solver.solve_best

    def recording(targets, starts=(), **kw):
        calls.append(([np.array(X0) for X0 in starts], kw))
        return original(targets, starts=starts, **kw)

    solver.solve_best = recording
    state.set_ground_truth(True)
    np.testing.assert_allclose(state.X_gt, state.mesh.V, atol=1e-6)  # at rest the ground truth is the rest pose
    assert len(calls) == 1 and calls[0][1]["keep"] == "first"
    X_gt0, X0 = state.X_gt.copy(), state.X.copy()
    _drag(state, 0, state.Q[0] + _offset(state))
    assert len(calls) == 2  # the release, not the 6 drag frames
    starts, _kw = calls[1]
    np.testing.assert_allclose(starts[0], X_gt0 + state.X - X0, atol=1e-9)  # the previous one moved by D's step
    np.testing.assert_allclose(starts[1], state.X)
    assert state.gt_result.converged
    np.testing.assert_allclose(state.X_gt[state.shape.handles], state.shape.targets(state.Q), atol=1e-8)
    assert 0 < state.gt_error["rms"] < 0.1  # a DefOp trained on 12 samples is close, not equal
    assert "error rms" in readout_text(state)
    state.set_ground_truth(False)
    assert state.gt_error is None and "ground truth" not in readout_text(state)


# ---------------------------------------------------------------------------------------------- views
def test_canvas_picture_follows_the_state(state):
    view = dop.editor.widgets.CanvasView(state, interactive=False)
    before = _png(view.png())
    state.set_handle(0, state.P[0] + _offset(state))
    view.refresh()
    after = _png(view.png())
    assert before.shape == after.shape
    assert np.mean(np.any(np.abs(after - before) > 30, axis=2)) > 0.005  # the picture changed
    uv = view.handle_fractions()[0]  # the dragged handle is drawn red where handle_fractions says
    h, w = after.shape[:2]
    patch = after[int(uv[1] * h) - 2 : int(uv[1] * h) + 3, int(uv[0] * w) - 2 : int(uv[0] * w) + 3]
    assert (patch[..., 0] > 150).any() and (patch[..., 0] - patch[..., 2] > 60).any(), patch


def test_matplotlib_mouse_events_drive_the_state(editor):
    s, canvas = editor.state, editor.canvas

    def mouse(name, xy, button=1):
        canvas.fig.canvas.draw()
        x, y = canvas.ax.transData.transform(xy)
        canvas.fig.canvas.callbacks.process(name, MouseEvent(name, canvas.fig.canvas, x, y, button=button))

    start = s.Q[0].copy()
    target = start + _offset(s)
    mouse("button_press_event", start)
    assert s.active == 0
    mouse("motion_notify_event", 0.5 * (start + target))
    mouse("motion_notify_event", target)
    mouse("button_release_event", target)
    assert s.active is None
    pixel = (canvas.xlim[1] - canvas.xlim[0]) / canvas.ax.bbox.width  # MouseEvent rounds to whole pixels
    np.testing.assert_allclose(s.Q[0], target, atol=2 * pixel)
    mouse("button_press_event", s.Q[0], button=3)  # the right button does not pick
    assert s.active is None
    sx, sy = editor.controls.sliders[0]  # the controls followed the mouse
    assert (sx.value, sy.value) == pytest.approx(tuple(s.Q[0]))
    assert f"{s.Q[0, 0]:.3f}" in editor.controls.handle_readout.value


def test_controls_drive_the_state(editor):
    s, c = editor.state, editor.controls
    c.basis.value = "linear"
    assert s.kind == "linear"
    sx, sy = c.sliders[0]
    sy.value = float(s.P[0, 1] - 0.1 * s.diag)  # a slider moves the handle
    assert s.Q[0, 1] == pytest.approx(sy.value)
    np.testing.assert_allclose(s.X[s.shape.moving_handles], s.Q, atol=1e-8)
    c.reset.click()
    np.testing.assert_allclose(s.Q, s.P)
    assert (sx.value, sy.value) == pytest.approx(tuple(s.P[0]))
    assert "linear: evaluation" in c.readout.value
    assert editor.widget.children[1].value[:8] == b"\x89PNG\r\n\x1a\n"  # without ipympl: a picture


def test_static_bundle_is_a_picture_and_a_line(state):
    bundle = dop.editor.widgets.static_bundle(state)
    import base64

    image = _png(base64.b64decode(bundle["image/png"]))
    assert image.shape[0] > 100 and image.shape[1] > 200
    assert "bar" in bundle["text/plain"] and "tps" in bundle["text/plain"]
