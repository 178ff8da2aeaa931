"""The page of a MovableOp (:mod:`defop.editor.movable_page`, ``static/defop_movable.js``): handles that move at rest.

- The page's module is run in Node against the Python frame of the same shipped (compressed, float32) operator at
  random placements and Q (hypothesis): equal to Python's float64 evaluation of the shipped factors up to float64
  round-off, and to the operator's own float32 frame within the float32 bound; handles and rest pose exact.
- The standalone page in headless Chromium: Shift-drag a rest handle to another vertex of its region, then drag a
  moving handle; bad placements (outside the region, onto another handle) are refused with a visible message.
"""

# ruff: noqa: F811  (the shape fixture of tests/test_movable.py, imported)

from __future__ import annotations

import base64
import json
import subprocess
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_browser_editor import NODE, U32, chromium_page, needs_node
from test_movable import shape  # noqa: F401  (the fixture: the rectangle, about 250 vertices, handles 0, 1 moving)

import defop as dop
from defop.editor import export, movable_page, payload
from defop.operator.movable import correct
from defop.scene.placement import placement_regions
from defop.training.movable import train_movable

DRIVER = movable_page.MOVABLE_JS_PATH.parents[3] / "tests" / "js" / "eval_movable.mjs"


@pytest.fixture(scope="module")
def op(shape, tmp_path_factory):
    """A small MovableOp (m = 40, fast mode, cached), handle 0 movable, compressed to float32 as pages ship."""
    import os

    os.environ.setdefault("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    placement = placement_regions(shape, [0], radius=0.15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, _ = train_movable(shape, placement, m=40, seed=0, n_jobs=1, progress=False)
    return op.compress()


def shipped_frame(op, Q, idx):
    """Python's float64 evaluation of the shipped factors (float32 A, B) at placement idx: what the page computes."""
    st_ = op.at(np.asarray(idx, np.int64))
    u = (op.delta_psi(Q[None], st_) @ op.factors[0].astype(float)) @ op.factors[1].astype(float)
    return correct(op.mesh, op.placement, op.handles, op.moving, st_, u, Q[None]).reshape(-1, op.d)


def float32_bound(op, Q, idx):
    """|X_page − X_python| per coordinate, with X_python the operator's own float32 frame: the other page tests'
    bound u Σ_j |δψ_j| |W_F,jc| with W_F = A B stored in float32, counted four times (the page's storage, and the
    Python frame's float32 rule: δψ cast, diag(s) A cast, float32 sums), carried by the correction (the residual at
    v_ℓ spreads with the bump, weights in [0, 1]), plus 1e-12 of the diagonal."""
    st_ = op.at(np.asarray(idx, np.int64))
    dpsi = np.abs(op.delta_psi(Q[None], st_))[0]
    A, B = (np.abs(f.astype(float)) for f in op.factors)
    e = (4 * U32 * (dpsi @ A) @ B).reshape(-1, op.d)
    sup, wt = st_.bumps
    e[sup] += np.abs(wt) @ e[st_.moved]
    return e + 1e-12 * op.mesh.bbox_diagonal


def page_operator(op):
    """The operator the standalone page evaluates: ``op`` with the page's factors (B on its grid,
    :func:`defop.editor.payload.page_factors`), as the fixed-P page tests take it."""
    from defop.operator.movable import MovableOp

    fresh = MovableOp(op.mesh, op.handles, op.moving, op.placement, op.basis, op.W, op.scales, dict(op.meta), op.reach)
    return fresh.set_factors(payload.page_factors(op))


def python_frame(op, Q, idx):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        return op(Q, np.asarray(idx, np.int64))


def node_steps(op, steps, tmp_path, restrict=None):
    """Run tests/js/eval_movable.mjs on the page's payload of ``op`` (passed through ``restrict`` if given) and the
    steps (frames and setRest calls)."""
    p = movable_page.movable_to_payload(op)
    meta, data = payload.encode_payload(p if restrict is None else restrict(p))
    spec = {
        "js": str(payload.JS_PATH),
        "movable": str(movable_page.MOVABLE_JS_PATH),
        "meta": meta,
        "data": base64.b64encode(data).decode(),
        "steps": steps,
    }
    path = tmp_path / "input.json"
    path.write_text(json.dumps(spec))
    res = subprocess.run([NODE, str(DRIVER), str(path)], capture_output=True, text=True, timeout=60, check=True)
    return json.loads(res.stdout)


def moving_vertices(op, idx):
    return op.placement.handles_at(np.asarray(idx, np.int64))[op.moving]


# ---------------------------------------------------------------------------------------------- Node
def check_frame(op, X, Q, v, keep=None):
    """The page's frame X at placement [v] and Q (of the vertices ``keep``, default all): handles on their targets,
    fixed ones at rest, Python's float64 evaluation of the shipped factors up to float64 round-off (the same formula)
    and the operator's own (float32) frame within the float32 bound on the free vertices."""
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    keep = np.arange(op.n_vertices) if keep is None else keep
    hm = moving_vertices(op, [v])
    assert np.abs(X[np.searchsorted(keep, hm)] - Q).max() <= 1e-12 * diag, "handles not on target (Prop. 2)"
    fixed = op.handles[~op.moving]
    np.testing.assert_array_equal(X[np.searchsorted(keep, fixed)], V[fixed])
    assert np.abs(X - shipped_frame(op, Q, [v])[keep]).max() <= 1e-12 * diag
    free = ~np.isin(keep, hm)
    bound = float32_bound(op, Q, [v])[keep]
    err = np.abs(X - python_frame(op, Q, [v])[keep])
    assert np.all(err[free] <= bound[free]), (err / bound).max()


def check_random_placements(op, tmp, spread, examples):
    """The page's module in Node at random region vertices of rest handle 0 and random Q (hypothesis, each
    coordinate within ``spread`` of the diagonal): the handle (and its patch) moved, the rest pose x bit for bit
    (8b), the moving handles exactly Q (Prop. 2) and the frame as :func:`check_frame` says."""
    V, diag, n, d = op.mesh.V, op.mesh.bbox_diagonal, op.n_moving, op.d
    region = op.placement.vertices[0]

    @settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.integers(0, len(region) - 1), st.lists(st.floats(-spread, spread), min_size=n * d, max_size=n * d))
    def check(k, dq):
        v = int(region[k])
        hm = moving_vertices(op, [v])
        Q = V[hm] + np.reshape(dq, (n, d)) * diag
        out = node_steps(op, [{"rest": [0, v]}, {"Q": V[hm].ravel().tolist()}, {"Q": Q.ravel().tolist()}], tmp)
        assert out[0]["placement"] == [v]
        np.testing.assert_array_equal(np.reshape(out[0]["P"], (-1, d)), V[hm])  # every member of the patch moved
        X_rest, X = (np.array(o["X"]).reshape(-1, d) for o in out[1:])
        np.testing.assert_array_equal(X_rest, V)  # (8b) bit for bit at the new placement
        assert np.array_equal(X[hm], Q), "moving handles not exact (Prop. 2)"
        check_frame(op, X, Q, v)

    check()


@needs_node
def test_javascript_matches_the_shipped_operator_at_random_placements(op, tmp_path_factory):
    check_random_placements(op, tmp_path_factory.mktemp("movable"), 0.08, 8)


@needs_node
def test_javascript_uncompressed_operator(op, tmp_path):
    """Without factors the page ships W_F in float32 (one factor): the same formula."""
    from defop.operator.movable import MovableOp

    full = MovableOp(op.mesh, op.handles, op.moving, op.placement, op.basis, op.W, op.scales, dict(op.meta), op.reach)
    v = int(full.placement.vertices[0][-1])
    Q = full.mesh.V[moving_vertices(full, [v])] + [[0.04, -0.03], [-0.02, 0.05]]
    out = node_steps(full, [{"rest": [0, v]}, {"Q": Q.ravel().tolist()}], tmp_path)
    st_ = full.at(np.array([v]))
    u = full.delta_psi(Q[None], st_) @ full.WF.astype(np.float32).astype(float)
    X = correct(full.mesh, full.placement, full.handles, full.moving, st_, u, Q[None]).reshape(-1, 2)
    assert np.abs(np.reshape(out[1]["X"], (-1, 2)) - X).max() <= 1e-12 * full.mesh.bbox_diagonal


@needs_node
def test_javascript_refuses_bad_placements(op, tmp_path):
    nominal = int(op.placement.nominal[0])
    outside = int(np.setdiff1d(np.arange(op.n_vertices), np.concatenate([op.placement.vertices[0], op.handles]))[0])
    steps = [{"rest": [0, outside]}, {"rest": [0, int(op.handles[1])]}, {"rest": [0, int(op.handles[2])]}]
    steps += [{"rest": [0, 2.5]}, {"rest": [1, nominal]}]
    out = node_steps(op, steps, tmp_path)
    P = op.mesh.V[op.handles[op.moving]].ravel().tolist()
    for o in out:
        assert o["placement"] == [nominal] and o["P"] == P, o  # nothing changed
    assert "outside rest handle 0's placement region" in out[0]["error"]
    assert "holds handle 1" in out[1]["error"] and "holds handle 2" in out[2]["error"]
    assert "not a vertex" in out[3]["error"] and "1 movable handles" in out[4]["error"]
    assert all(o["error"].startswith("RangeError") for o in out)


# ---------------------------------------------------------------------------------------------- Chromium
def screen(page, x, y):
    """The page position (px) of mesh point (x, y)."""
    box = page.locator("canvas.defop-canvas").bounding_box()
    u, v = page.evaluate("([x, y]) => window.defopEditor.st.view.toScreen(x, y)", [float(x), float(y)])
    return box["x"] + u, box["y"] + v


def pointer_path(page, start, end, steps=6):
    page.mouse.move(*start)
    page.mouse.down()
    for t in np.linspace(0.2, 1.0, steps):
        page.mouse.move(start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))
        page.wait_for_timeout(20)
    page.mouse.up()


STATE_JS = (
    "() => { const e = window.defopEditor; return {Q: Array.from(e.st.Q), X: Array.from(e.st.X),"
    " placement: e.st.op.placement(), msg: e.ui.box.querySelector('.defop-rest-msg').textContent,"
    " shown: e.ui.box.querySelector('.defop-rest-msg').checkVisibility()} }"
)


@pytest.mark.browser
def test_page_moves_a_rest_handle_then_drags(op, shape, tmp_path):
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    region = op.placement.vertices[0]
    nominal = int(op.placement.nominal[0])
    v = int(region[np.argmax(np.linalg.norm(V[region] - V[nominal], axis=1))])  # the farthest vertex of the region
    path = export.to_html(op, tmp_path / "movable.html", shape=shape)
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        # Shift-drag the rest handle to (near) vertex v: it snaps to v, the shape stays at rest
        target = V[v] + 0.004 * diag
        page.keyboard.down("Shift")
        pointer_path(page, screen(page, *V[nominal]), screen(page, *target))
        page.keyboard.up("Shift")
        moved = page.evaluate(STATE_JS)
        # then drag moving handle 0 (now at V[v]) as usual
        start = screen(page, *V[v])
        pointer_path(page, start, (start[0] + 30, start[1] - 25))
        dragged = page.evaluate(STATE_JS)
        # bad placements, with the toggle on: outside the region, onto another handle; nothing changes
        page.locator("button.defop-rest-toggle").click()
        here = np.array(dragged["X"]).reshape(-1, 2)[v]
        pointer_path(page, screen(page, *here), screen(page, *(here + [0.0, -0.3 * diag])))
        outside = page.evaluate(STATE_JS)
        pointer_path(page, screen(page, *here), screen(page, *np.array(dragged["X"]).reshape(-1, 2)[op.handles[1]]))
        onto = page.evaluate(STATE_JS)
        by_code = page.evaluate(f"() => window.defopEditor.setRest(0, {int(op.handles[2])})")
        coded = page.evaluate(STATE_JS)
        page.locator("button.defop-rest-toggle").click()
        page.locator("button.defop-reset").click()
        reset = page.evaluate(STATE_JS)
        legend = " ".join(page.locator(".defop-legend").text_content().split())
        said = page.locator(".defop-instruction").text_content()
        errors = page.errors
    assert not errors, errors
    assert "placement region of a rest handle" in legend and "Shift-drag" in said
    hm = moving_vertices(op, [v])
    # the rest move: snapped to v, Q = the new P, X = x bit for bit
    assert moved["placement"] == [v] and moved["msg"] == ""
    np.testing.assert_array_equal(np.reshape(moved["Q"], (-1, 2)), V[hm])
    np.testing.assert_array_equal(np.reshape(moved["X"], (-1, 2)), V)
    # the drag at the new placement
    Q, X = np.reshape(dragged["Q"], (-1, 2)), np.reshape(dragged["X"], (-1, 2))
    assert dragged["placement"] == [v] and np.linalg.norm(Q[0] - V[v]) > 0.01 * diag
    assert np.abs(X[hm] - Q).max() <= 1e-12 * diag  # the handles on their targets
    shipped = page_operator(op)  # B on its grid, as the fixed-P page ships it
    assert np.abs(X - shipped_frame(shipped, Q, [v])).max() <= 1e-12 * diag
    err = np.abs(X - python_frame(shipped, Q, [v]))
    free = np.setdiff1d(np.arange(op.n_vertices), op.handles)
    bound = float32_bound(shipped, Q, [v])
    assert np.all(err[free] <= bound[free]), (err / bound).max()
    assert np.abs(X - python_frame(op, Q, [v])).max() <= 1e-3 * diag  # the grid moves the frame little
    # refused, visibly, with nothing changed
    for bad, words in ((outside, "outside rest handle 0's placement region"), (onto, "onto handle 1")):
        assert words in bad["msg"] and bad["shown"], bad["msg"]
        assert bad["placement"] == [v] and bad["Q"] == dragged["Q"] and bad["X"] == dragged["X"]
    assert by_code is False and "holds handle 2" in coded["msg"] and coded["X"] == dragged["X"]
    # Reset: the rest pose of the new placement, exact
    assert reset["placement"] == [v]
    np.testing.assert_array_equal(np.reshape(reset["X"], (-1, 2)), V)


# ---------------------------------------------------------------------------------------------- the editor's state
def rest_state(op, shape):
    from defop.editor.state import EditorState

    return EditorState(shape, {"tps": op}, kinds=("tps",))


def snapshot(s):
    return {k: np.copy(getattr(s, k)) for k in ("Q", "X", "P", "rest")} | {"regions": repr(s.regions)}


def assert_same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]) if k != "regions" else a[k] == b[k], k


def test_state_shift_drag_moves_a_rest_handle_then_drags(op, shape):
    s = rest_state(op, shape)
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    nominal, region = int(op.placement.nominal[0]), op.placement.vertices[0]
    v = int(region[np.argmax(np.linalg.norm(V[region] - V[nominal], axis=1))])
    assert s.rest.tolist() == [nominal] and np.array_equal(s.X, V)
    assert s.press(*V[nominal], shift=True) == 0 and s.active is None  # a rest handle, not a moving one
    assert s.drag(*(V[v] + 0.004 * diag)) and s.rest_target == v  # the drag shows the snap
    assert s.drag(*(V[v] + 0.4 * diag)) and s.rest_target is None  # outside: no place
    s.release(*(V[v] + 0.004 * diag))
    hm = moving_vertices(op, [v])
    assert s.rest.tolist() == [v] and np.array_equal(s.P, V[hm]) and np.array_equal(s.Q, V[hm])
    np.testing.assert_array_equal(s.X, V)  # (8b) at the new placement, bit for bit
    assert s.shape.handles[0] == v and s.outside_regions() == []  # the sampling regions moved with the rest
    # then an ordinary drag of moving handle 0 from its new rest position
    assert s.press(*V[v]) == 0
    s.drag(*(V[v] + [0.05, 0.04]))
    s.release()
    Q = V[hm] + [[0.05, 0.04], [0.0, 0.0]]
    np.testing.assert_array_equal(s.Q, Q)
    np.testing.assert_array_equal(s.X, python_frame(op, Q, [v]))
    np.testing.assert_array_equal(s.X[hm], Q)
    # while deformed, moving the rest keeps q − p (retarget); back at the nominal vertex by index
    s.set_rest(0, nominal)
    np.testing.assert_allclose(s.Q - s.P, Q - V[hm], rtol=0, atol=1e-15)
    assert s.rest.tolist() == [nominal]


def test_state_refuses_bad_rest_placements(op, shape):
    s = rest_state(op, shape)
    diag = op.mesh.bbox_diagonal
    nominal = int(op.placement.nominal[0])
    s.set_Q(s.P + [[0.03, -0.02], [0.01, 0.02]])
    before = snapshot(s)
    outside = int(np.setdiff1d(np.arange(op.n_vertices), np.concatenate([op.placement.vertices[0], op.handles]))[0])
    bad = [
        ((0, outside), "outside rest handle 0's placement region"),
        ((0, int(op.handles[1])), "holds handle 1"),
        ((0, int(op.handles[2])), "holds handle 2"),
        ((0, s.X[op.handles[1]]), "onto handle 1"),
        ((0, s.X[nominal] + [0.0, 0.3 * diag]), "outside rest handle 0's placement region"),
        ((1, nominal), "out of range"),
        ((0, [np.nan, 0.0]), "finite|NaN"),
    ]
    for args, words in bad:
        with pytest.raises(ValueError, match=words):
            s.set_rest(*args)
        assert_same(snapshot(s), before)
    # the pointer: the toggle on, a release outside the region is refused, the drag ends, nothing else changes
    s.set_rest_mode(True)
    assert s.press(*s.X[nominal]) == 0
    with pytest.raises(ValueError, match="outside rest handle 0's placement region"):
        s.release(*(s.X[nominal] + [0.0, 0.3 * diag]))
    assert s.rest_active is None
    assert_same(snapshot(s), before)


def test_state_rest_mode_needs_a_movable_operator(op, shape):
    from defop.editor.state import EditorState

    fixed = EditorState(shape, trainer=lambda sh, kind: dop.train(sh, basis=kind, m=12, progress=False, n_jobs=1)[0])
    with pytest.raises(ValueError, match="MovableOp"):
        fixed.set_rest_mode(True)
    with pytest.raises(ValueError, match="MovableOp"):
        fixed.set_rest(0, 0)
    assert fixed.press(*fixed.P[0], shift=True) == 0 and fixed.active == 0  # Shift is an ordinary press here
    with pytest.raises(ValueError, match="one operator"):
        EditorState(shape, {"tps": op})  # a basis menu would switch to fixed-P operators


def test_state_ground_truth_at_a_moved_rest(op, shape):
    s = rest_state(op, shape)
    v = int(op.placement.vertices[0][0])
    s.set_rest(0, v)
    s.set_handle(0, s.P[0] + [0.04, 0.03])
    s.set_ground_truth(True)
    hm = moving_vertices(op, [v])
    np.testing.assert_allclose(s.X_gt[hm], s.Q, atol=1e-9)  # the solve holds the handles at the moved rest
    assert s.gt_error["max"] < 0.05


def test_widget_kernel_side_of_the_rest_mode(op, shape):
    """What the page sends (rest on a rest move) reaches the state, retargeted; a refused rest is sent back."""
    from defop.editor import browser

    editor = browser.BrowserEditor(shape, {"tps": op}, kinds=("tps",))
    assert editor.payload_meta["scalars"]["movable"] == 1 and "defop_movable.js" in editor._esm
    assert "MODES.movable" in editor._esm and 'from "./defop_editor.js"' not in editor._esm
    nominal, v = int(op.placement.nominal[0]), int(op.placement.vertices[0][0])
    assert editor.rest == [nominal]
    Q = editor.Q + [[0.02, 0.01], [0.0, 0.0]]
    editor.q = Q.ravel().tolist()
    editor.rest = [v]  # as the page does on a rest move
    assert editor.state.rest.tolist() == [v]
    dq = op.mesh.V[v] - op.mesh.V[nominal]
    np.testing.assert_array_equal(editor.Q[0], Q[0] + dq)  # q − p kept, by Python's retarget
    assert editor.q == editor.state.Q.ravel().tolist()
    with pytest.raises(ValueError, match="holds handle 1"):
        editor.rest = [int(op.handles[1])]
    assert editor.rest == [v] and editor.state.rest.tolist() == [v]  # the trait is sent back
    with pytest.raises(ValueError, match="list of 1"):
        editor.rest = [v, v]
    assert editor.rest == [v]


_FAKE_MODEL = """
const values = JSON.parse(document.getElementById("traits").textContent), handlers = {};
const bytes = (b64) => { const s = atob(b64), u = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) u[i] = s.charCodeAt(i); return new DataView(u.buffer); };
for (const k of ["payload_data", "gt_data", "image_data"]) values[k] = bytes(values[k]);
window.sent = [];
const model = { get: (k) => values[k], set: (k, v) => { values[k] = v; window.sent.push([k, v]); },
  save_changes: () => {}, on: (event, f) => { (handlers[event] = handlers[event] || []).push(f); } };
window.fromPython = (k, v) => { values[k] = v; for (const f of handlers["change:" + k] || []) f(); };
const root = document.getElementById("app");
render({ model, el: root });
window.defopEditor = root.defopEditor;
"""


@pytest.mark.browser
def test_widget_view_moves_a_rest_handle(op, shape, tmp_path):
    """The anywidget view's own module (BrowserEditor._esm) with a stand-in for the widget model, in Chromium."""
    from defop.editor import browser

    widget = browser.BrowserEditor(shape, {"tps": op}, kinds=("tps",))
    traits = {k: getattr(widget, k) for k in ("payload_meta", "q", "rest", "gt_meta", "image_meta")}
    for k in ("payload_data", "gt_data", "image_data"):
        traits[k] = base64.b64encode(getattr(widget, k)).decode()
    page_text = (
        f'<!DOCTYPE html><html><body><div id="app"></div><script id="traits" type="application/json">'
        f'{export.script_json(traits)}</script><script type="module">\n{widget._esm}\n{_FAKE_MODEL}</script>'
        "</body></html>"
    )
    (tmp_path / "widget.html").write_text(page_text)
    V = op.mesh.V
    nominal, region = int(op.placement.nominal[0]), op.placement.vertices[0]
    v, w = (int(u) for u in region[np.argsort(np.linalg.norm(V[region] - V[nominal], axis=1))[-2:]])
    with chromium_page() as page:
        page.goto((tmp_path / "widget.html").as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        page.keyboard.down("Shift")
        pointer_path(page, screen(page, *V[nominal]), screen(page, *V[v]))
        page.keyboard.up("Shift")
        sent = page.evaluate("() => window.sent")
        widget.rest = sent[-1][1]  # the kernel places it, and answers with q
        placed, P_placed = widget.state.rest.tolist(), widget.state.P.copy()
        page.evaluate("([q]) => window.fromPython('q', q)", [widget.q])
        moved = page.evaluate(STATE_JS)
        widget.state.set_rest(0, w)  # Python moves it: the page follows the traits
        widget._resync()
        page.evaluate(
            "([rest, q]) => { window.fromPython('rest', rest); window.fromPython('q', q); }", [widget.rest, widget.q]
        )
        followed = page.evaluate(STATE_JS)
        errors = page.errors
    assert not errors, errors
    assert sent == [["rest", [v]]]  # only the rest: Python retargets q
    assert placed == [v] and moved["placement"] == [v]
    np.testing.assert_array_equal(np.reshape(moved["Q"], (-1, 2)), P_placed)
    np.testing.assert_array_equal(np.reshape(moved["X"], (-1, 2)), V)  # (8b) at the new placement
    assert followed["placement"] == [w] and followed["Q"] == widget.q
    np.testing.assert_array_equal(np.reshape(followed["X"], (-1, 2)), V)
