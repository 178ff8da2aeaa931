"""The page of a 3D MovableOp (:mod:`defop.editor.movable_page`, ``static/defop_movable.js`` in the 3D view of
``static/defop_solid.js``): a movable handle is a patch of vertices that moves at rest by one offset.

- The page's evaluator (``makeMovable``, the 2D page's, the dimension read from the payload) in Node against the
  Python frame of the same shipped (compressed, float32) operator at random placements and Q (hypothesis): equal to
  Python's float64 evaluation of the shipped factors up to float64 round-off, to the operator's own float32 frame
  within the float32 bound of the 2D page's tests; every member of the moved patch exact, rest pose exact.
- The standalone 3D page in headless Chromium: Shift-drag the movable handle onto another vertex of its region (the
  patch moves with it), then drag a moving handle in the view plane; a bad placement (outside the region, onto
  another handle) is refused with a visible message and nothing changes.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_browser_editor import chromium_page, needs_node
from test_page_3d import _drag
from test_page_movable import float32_bound, moving_vertices, node_steps, python_frame, shipped_frame

import defop as dop
from defop.editor import export
from defop.scene.placement import placement_regions
from defop.training.movable import train_movable


@pytest.fixture(scope="module")
def bar():
    """bar_3d at about 300 vertices: 4 fixed handles on one end face, a patch of 4 moving ones on the other."""
    return dop.shapes.load("bar_3d", n_vertices=300)


@pytest.fixture(scope="module")
def op(bar, tmp_path_factory):
    """A small 3D MovableOp (m = 12, fast mode, cached): handle 4 movable with its patch (handles 4-7), compressed to
    float32 as pages ship."""
    import os

    os.environ.setdefault("DEFOP_CACHE", str(tmp_path_factory.mktemp("cache")))
    placement = placement_regions(bar, [4], radius=0.08 * bar.mesh.bbox_diagonal)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, _ = train_movable(bar, placement, m=12, seed=0, n_jobs=1, progress=False)
    return op.compress()


def check_frame(op, X, Q, v):
    """The page's frame X at placement [v] and Q: handles on their targets, fixed ones at rest, the shipped factors'
    float64 frame up to round-off and the operator's own frame within the float32 bound on the free vertices."""
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    hm = moving_vertices(op, [v])
    assert np.abs(X[hm] - Q).max() <= 1e-12 * diag, "the patch's handles are not on their targets (Prop. 2)"
    fixed = op.handles[~op.moving]
    np.testing.assert_array_equal(X[fixed], V[fixed])
    assert np.abs(X - shipped_frame(op, Q, [v])).max() <= 1e-12 * diag
    free = np.setdiff1d(np.arange(op.n_vertices), hm)
    bound = float32_bound(op, Q, [v])
    err = np.abs(X - python_frame(op, Q, [v]))
    assert np.all(err[free] <= bound[free]), (err / bound).max()


# ---------------------------------------------------------------------------------------------- Node
@needs_node
def test_javascript_matches_the_shipped_operator_in_3d(op, tmp_path_factory):
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    region = op.placement.vertices[0]
    tmp = tmp_path_factory.mktemp("movable3d")

    @settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.integers(0, len(region) - 1), st.lists(st.floats(-0.05, 0.05), min_size=12, max_size=12))
    def check(k, dq):
        v = int(region[k])
        hm = moving_vertices(op, [v])
        assert not np.array_equal(hm, op.handles[op.moving]) or v == op.placement.nominal[0]
        Q = V[hm] + np.reshape(dq, (4, 3)) * diag
        out = node_steps(op, [{"rest": [0, v]}, {"Q": V[hm].ravel().tolist()}, {"Q": Q.ravel().tolist()}], tmp)
        assert out[0]["placement"] == [v]
        np.testing.assert_array_equal(np.reshape(out[0]["P"], (-1, 3)), V[hm])  # the whole patch moved
        X_rest, X = (np.array(o["X"]).reshape(-1, 3) for o in out[1:])
        np.testing.assert_array_equal(X_rest, V)  # (8b) bit for bit at the new placement
        assert np.array_equal(X[hm], Q), "moving handles not exact (Prop. 2)"
        check_frame(op, X, Q, v)

    check()


@needs_node
def test_javascript_refuses_bad_placements_in_3d(op, tmp_path):
    nominal = int(op.placement.nominal[0])
    pl = op.placement
    outside = int(np.setdiff1d(np.arange(op.n_vertices), np.concatenate([pl.vertices[0], op.handles]))[0])
    steps = [{"rest": [0, outside]}, {"rest": [0, int(op.handles[1])]}, {"rest": [0, int(op.handles[6])]}]
    out = node_steps(op, steps, tmp_path)
    P = op.mesh.V[op.handles[op.moving]].ravel().tolist()
    for o in out:
        assert o["placement"] == [nominal] and o["P"] == P, o  # nothing changed
    assert "outside rest handle 0's placement region" in out[0]["error"]
    assert "holds handle 1" in out[1]["error"]
    assert "outside rest handle 0's placement region" in out[2]["error"]  # a patch sibling's vertex is not a place


# ---------------------------------------------------------------------------------------------- Chromium
E = "window.defopEditor"
STATE_JS = (
    f"() => {{ const e = {E}; return {{Q: Array.from(e.st.Q), X: Array.from(e.st.X), S: Array.from(e.st.S),"
    " placement: e.st.op.placement(), handles: Array.from(e.st.p.handles),"
    " msg: e.ui.box.querySelector('.defop-rest-msg').textContent,"
    " shown: e.ui.box.querySelector('.defop-rest-msg').checkVisibility()} }"
)


def open_page(page, op, bar, tmp_path):
    path = export.to_html(op, tmp_path / "movable3d.html", shape=bar)
    page.goto(path.as_uri())
    page.wait_for_function(f"() => {E} && {E}.st.X")
    assert page.evaluate(f"() => {E}.webgl"), "no WebGL in this Chromium"
    return page.locator("canvas.defop-canvas").bounding_box()


def screen(page, box, w):
    u, v = page.evaluate(f"(w) => {E}.vertexScreen(w)", int(w))
    return box["x"] + u, box["y"] + v


def pointer_path(page, start, end, steps=6):
    page.mouse.move(*start)
    page.mouse.down()
    for t in np.linspace(0.2, 1.0, steps):
        page.mouse.move(start[0] + t * (end[0] - start[0]), start[1] + t * (end[1] - start[1]))
        page.wait_for_timeout(20)
    page.mouse.up()


def lonely_region_vertex(page, op):
    """The region vertex (not the nominal) farthest on screen from every other region vertex and handle."""
    pl = op.placement
    pts = np.array(page.evaluate(f"(ws) => ws.map((w) => {E}.vertexScreen(w))", pl.vertices[0].tolist()))
    hs = np.array(page.evaluate(f"(ws) => ws.map((w) => {E}.vertexScreen(w))", op.handles.tolist()))
    others = np.delete(hs, pl.members[0], axis=0)
    gap = []
    for i, w in enumerate(pl.vertices[0]):
        near = np.concatenate([np.delete(pts, i, axis=0), others])
        gap.append(-1.0 if w == pl.nominal[0] else np.linalg.norm(near - pts[i], axis=1).min())
    i = int(np.argmax(gap))
    assert gap[i] > 4, gap  # the pointer picks it without doubt
    return int(pl.vertices[0][i])


@pytest.mark.browser
def test_page_3d_moves_a_rest_patch_then_drags(op, bar, tmp_path):
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    nominal = int(op.placement.nominal[0])
    with chromium_page() as page:
        box = open_page(page, op, bar, tmp_path)
        start = page.evaluate(STATE_JS)
        v = lonely_region_vertex(page, op)
        u0 = screen(page, box, nominal)
        u1 = screen(page, box, v)
        page.keyboard.down("Shift")
        pointer_path(page, u0, (u1[0] + 1.0, u1[1] - 1.0))  # a pixel off: it snaps to v
        page.keyboard.up("Shift")
        moved = page.evaluate(STATE_JS)
        drag = _drag(page, box, E, 1, 35.0, -30.0)  # moving handle 1: a member of the moved patch
        dragged = page.evaluate(STATE_JS)
        page.locator("button.defop-reset").click()
        reset = page.evaluate(STATE_JS)
        legend = " ".join(page.locator(".defop-legend").text_content().split())
        said = page.locator(".defop-instruction").text_content()
        balls = page.evaluate(f"() => {E}.regionBalls.map((b) => b.visible)")
        errors = page.errors
    assert not errors, errors
    assert "placement region of a rest handle" in legend and "Shift-drag" in said
    assert len(balls) == len(op.placement.vertices[0]) and all(balls)  # the region drawn
    hm = moving_vertices(op, [v])
    # the rest move: snapped to v, the whole patch moved by one offset, Q = the new P, X = x bit for bit
    assert start["placement"] == [nominal] and moved["placement"] == [v] and moved["msg"] == ""
    assert not np.array_equal(hm, op.handles[op.moving])
    assert moved["handles"] == op.placement.handles_at(np.array([v])).tolist()
    np.testing.assert_array_equal(np.reshape(moved["Q"], (-1, 3)), V[hm])
    np.testing.assert_array_equal(np.reshape(moved["X"], (-1, 3)), V)
    # the drag at the new placement
    assert drag["held"]["active"] == 1
    Q, X = np.reshape(dragged["Q"], (-1, 3)), np.reshape(dragged["X"], (-1, 3))
    assert dragged["placement"] == [v] and np.linalg.norm(Q[1] - V[hm[1]]) > 0.02 * diag
    np.testing.assert_array_equal(np.delete(Q, 1, axis=0), np.delete(V[hm], 1, axis=0))
    check_frame(op, X, Q, v)
    np.testing.assert_array_equal(np.reshape(dragged["S"], (-1, 3)), X)  # the drawn surface: X's boundary
    # Reset: the rest pose of the new placement, exact
    assert reset["placement"] == [v]
    np.testing.assert_array_equal(np.reshape(reset["Q"], (-1, 3)), V[hm])
    np.testing.assert_array_equal(np.reshape(reset["X"], (-1, 3)), V)


@pytest.mark.browser
def test_page_3d_refuses_bad_rest_placements(op, bar, tmp_path):
    nominal = int(op.placement.nominal[0])
    with chromium_page() as page:
        box = open_page(page, op, bar, tmp_path)
        _drag(page, box, E, 0, -30.0, 25.0)  # deformed first: nothing may change
        before = page.evaluate(STATE_JS)
        page.locator("button.defop-rest-toggle").click()
        here = screen(page, box, nominal)
        pointer_path(page, here, (here[0] + 0.0, box["y"] + 5.0))  # the canvas' top edge: no region vertex
        outside = page.evaluate(STATE_JS)
        pointer_path(page, here, screen(page, box, op.handles[0]))  # onto a fixed handle's sphere
        onto = page.evaluate(STATE_JS)
        by_code = page.evaluate(f"() => {E}.setRest(0, {int(op.handles[1])})")
        coded = page.evaluate(STATE_JS)
        errors = page.errors
    assert not errors, errors
    assert before["placement"] == [nominal] and before["Q"] != np.asarray(op.mesh.V[op.handles[4:]]).ravel().tolist()
    for bad, words in (
        (outside, "the pointer is outside rest handle 0's placement region"),
        (onto, "cannot move onto handle 0"),
        (coded, "holds handle 1"),
    ):
        assert words in bad["msg"] and bad["shown"], bad["msg"]
        for key in ("placement", "Q", "X", "handles"):
            assert bad[key] == before[key], key
    assert by_code is False
