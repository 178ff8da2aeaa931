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
from test_browser_editor import chromium_page, needs_node
from test_page_3d import drag_handle
from test_page_movable import (
    check_frame,
    check_random_placements,
    float32_bound,
    moving_vertices,
    node_steps,
    page_operator,
    pointer_path,
    python_frame,
    shipped_frame,
)
from test_page_surface import float32_bary_bound, split_surface

import defop as dop
from defop.editor import compact, export, movable_page, payload
from defop.geometry.volumetric.surface import EmbeddedSurface
from defop.scene.placement import placement_regions
from defop.training.movable import train_movable


@pytest.fixture(scope="module")
def bar():
    """bar_3d at about 300 vertices: 4 fixed handles on one end face, a patch of 4 moving ones on the other."""
    return dop.shapes.load("bar_3d", n_vertices=300)


@pytest.fixture(scope="module")
def surfaced(bar):
    """bar_3d with its own surface, embedded in its tetrahedra: the boundary split in four (tests/test_page_surface)."""
    B = bar.mesh.boundary_facets
    used = np.unique(B)
    renum = np.full(bar.mesh.n_vertices, -1)
    renum[used] = np.arange(len(used))
    surface = EmbeddedSurface.embed(bar.mesh, *split_surface(bar.mesh.V[used], renum[B]))
    return dop.Shape(
        name="bar_3d", mesh=bar.mesh, handles=bar.handles, moving=bar.moving, regions=bar.regions, surface=surface
    )


def check_surface(op, surface, S, X, Q, v, keep):
    """The page's surface S (its vertices, from X of the vertices ``keep``): the page's tetrahedra's barycentric
    combination (float32 coordinates, b_0 = 1 − Σ in float64) and, through them, the operator's own frame within the
    float32 bound carried by the coordinates."""
    diag = op.mesh.bbox_diagonal
    X_page = shipped_frame(op, Q, [v])  # equal to the page's X on its vertices up to float64 round-off
    X_page[keep] = X
    err = np.linalg.norm(S - surface.deform(X_page), axis=1)
    assert np.all(err <= float32_bary_bound(surface, X_page) + 1e-12 * diag), err.max() / diag
    T = surface.tets[surface.elements]
    carried = np.linalg.norm(np.einsum("sk,skc->sc", np.abs(surface.bary), float32_bound(op, Q, [v])[T]), axis=1)
    err = np.linalg.norm(S - surface.deform(python_frame(op, Q, [v])), axis=1)
    assert np.all(err <= carried + float32_bary_bound(surface, X_page) + 1e-12 * diag), err.max() / diag


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


# ---------------------------------------------------------------------------------------------- Node
@needs_node
def test_javascript_matches_the_shipped_operator_in_3d(op, tmp_path_factory):
    region = op.placement.vertices[0]
    assert len(region) > 1 and all(len(set(op.placement.layout[0][:, j])) > 1 for j in range(4))  # patches move
    check_random_placements(op, tmp_path_factory.mktemp("movable3d"), 0.05, 6)


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


@needs_node
def test_the_drawn_vertices_are_evaluated_as_the_full_page(op, tmp_path):
    """The page ships the drawn vertices and the placement's (movable_page.drawn_payload): each is evaluated bit for
    bit as in the full payload, at a moved placement, and the page speaks the operator's vertex indices."""
    v = int(op.placement.vertices[0][-1])
    hm = moving_vertices(op, [v])
    Q = op.mesh.V[hm] + 0.02 * op.mesh.bbox_diagonal * np.random.default_rng(3).normal(size=(4, 3))
    steps = [{"rest": [0, v]}, {"Q": Q.ravel().tolist()}, {"rest": [0, int(op.handles[1])]}]
    small = node_steps(op, steps, tmp_path, restrict=movable_page.drawn_payload)
    full = node_steps(op, steps, tmp_path)
    keep = movable_page.drawn_payload(movable_page.movable_to_payload(op))["drawn"]
    assert len(keep) < op.n_vertices and np.isin(np.concatenate(op.placement.layout).ravel(), keep).all()
    assert small[0]["placement"] == full[0]["placement"] == [v]
    np.testing.assert_array_equal(np.reshape(small[1]["X"], (-1, 3)), np.reshape(full[1]["X"], (-1, 3))[keep])
    assert small[2]["error"] == full[2]["error"] and "holds handle 1" in small[2]["error"]


@needs_node
def test_the_shipped_page_payload_is_quantised_as_the_fixed_p_page(op, tmp_path):
    """The standalone page's payload (export.movable_html): B on its grid and Rice-coded, as the fixed-P page's
    (payload.page_factors, compact.compact_payload), decoded in the page bit for bit; the drawn and placement vertices
    evaluate as Python's float64 evaluation of those factors, the moved patch and the rest pose exact."""
    shipped = page_operator(op)
    assert not np.array_equal(shipped.factors[1], op.factors[1])  # B moved to its grid
    np.testing.assert_array_equal(shipped.factors[0], op.factors[0])

    def page(p):
        p = movable_page.movable_to_payload(op, factors=payload.page_factors(op))
        out = compact.compact_payload(p, movable_page.drawn_payload)
        assert "B_rice" in out and "B" not in out and out["F"].dtype == np.uint16
        return out

    pl = op.placement
    keep = movable_page.drawn_payload(movable_page.movable_to_payload(op))["drawn"]
    rng = np.random.default_rng(7)
    for v in (int(pl.vertices[0][-1]), int(pl.vertices[0][1])):
        hm = moving_vertices(op, [v])
        Q = op.mesh.V[hm] + 0.03 * op.mesh.bbox_diagonal * rng.normal(size=hm.shape + (3,))
        out = node_steps(
            op,
            [{"rest": [0, v]}, {"Q": op.mesh.V[hm].ravel().tolist()}, {"Q": Q.ravel().tolist()}],
            tmp_path,
            restrict=page,
        )
        X_rest, X = (np.reshape(o["X"], (-1, 3)) for o in out[1:])
        np.testing.assert_array_equal(X_rest, op.mesh.V[keep])  # (8b) bit for bit at the new placement
        np.testing.assert_array_equal(X[np.searchsorted(keep, hm)], Q)  # Prop. 2: the patch and the others exact
        check_frame(shipped, X, Q, v, keep)


# ---------------------------------------------------------------------------------------------- Chromium
E = "window.defopEditor"
STATE_JS = (
    f"() => {{ const e = {E}; return {{Q: Array.from(e.st.Q), X: Array.from(e.st.X), S: Array.from(e.st.S),"
    " placement: e.st.op.placement(), handles: Array.from(e.st.p.handles, e.st.op.toMesh),"
    " msg: e.ui.box.querySelector('.defop-rest-msg').textContent,"
    " shown: e.ui.box.querySelector('.defop-rest-msg').checkVisibility()} }"
)


def open_page(page, op, bar, tmp_path):
    """The page of ``op``: its canvas' box and the page's vertices (indices into the operator's mesh)."""
    path = export.to_html(op, tmp_path / "movable3d.html", shape=bar)
    page.goto(path.as_uri())
    page.wait_for_function(f"() => {E} && {E}.st.X")
    assert page.evaluate(f"() => {E}.webgl"), "no WebGL in this Chromium"
    keep = np.array(page.evaluate(f"() => Array.from({E}.st.p.drawn || [])"), np.int64)
    keep = np.arange(op.n_vertices) if keep.size == 0 else keep  # every vertex drawn, or used by the surface
    return page.locator("canvas.defop-canvas").bounding_box(), keep


def screens(page, keep, ws):
    """Where the page draws vertices ``ws`` (the operator's indices), CSS pixels in the canvas: (k, 2)."""
    return np.array(page.evaluate(f"(ws) => ws.map((w) => {E}.vertexScreen(w))", np.searchsorted(keep, ws).tolist()))


def screen(page, box, keep, w):
    u, v = screens(page, keep, [int(w)])[0]
    return box["x"] + u, box["y"] + v


def lonely_region_vertex(page, op, keep):
    """The region vertex (not the nominal) farthest on screen from every other region vertex and handle."""
    pl = op.placement
    pts = screens(page, keep, pl.vertices[0])
    others = np.delete(screens(page, keep, op.handles), pl.members[0], axis=0)
    gap = []
    for i, w in enumerate(pl.vertices[0]):
        near = np.concatenate([np.delete(pts, i, axis=0), others])
        gap.append(-1.0 if w == pl.nominal[0] else np.linalg.norm(near - pts[i], axis=1).min())
    i = int(np.argmax(gap))
    assert gap[i] > 4, gap  # the pointer picks it without doubt
    return int(pl.vertices[0][i])


@pytest.mark.browser
def test_page_3d_moves_a_rest_patch_then_drags(op, surfaced, tmp_path):
    V, diag = op.mesh.V, op.mesh.bbox_diagonal
    nominal = int(op.placement.nominal[0])
    with chromium_page() as page:
        box, keep = open_page(page, op, surfaced, tmp_path)
        start = page.evaluate(STATE_JS)
        v = lonely_region_vertex(page, op, keep)
        u0 = screen(page, box, keep, nominal)
        u1 = screen(page, box, keep, v)
        page.keyboard.down("Shift")
        pointer_path(page, u0, (u1[0] + 1.0, u1[1] - 1.0))  # a pixel off: it snaps to v
        page.keyboard.up("Shift")
        moved = page.evaluate(STATE_JS)
        drag = drag_handle(page, box, E, 1, 35.0, -30.0)  # moving handle 1: a member of the moved patch
        dragged = page.evaluate(STATE_JS)
        page.locator("button.defop-reset").click()
        reset = page.evaluate(STATE_JS)
        legend = " ".join(page.locator(".defop-legend").text_content().split())
        said = page.locator(".defop-instruction").text_content()
        balls = page.evaluate(f"() => [{E}.regionBalls.count, {E}.regionBalls.mesh.visible]")
        errors = page.errors
    assert not errors, errors
    assert "placement region of a rest handle" in legend and "Shift-drag" in said
    assert balls == [len(op.placement.vertices[0]), True]  # the region drawn
    hm = moving_vertices(op, [v])
    # the rest move: snapped to v, the whole patch moved by one offset, Q = the new P, X = x bit for bit
    assert start["placement"] == [nominal] and moved["placement"] == [v] and moved["msg"] == ""
    assert not np.array_equal(hm, op.handles[op.moving])
    assert moved["handles"] == op.placement.handles_at(np.array([v])).tolist()
    np.testing.assert_array_equal(np.reshape(moved["Q"], (-1, 3)), V[hm])
    np.testing.assert_array_equal(np.reshape(moved["X"], (-1, 3)), V[keep])
    # the drag at the new placement
    assert drag["held"]["active"] == 1
    Q, X = np.reshape(dragged["Q"], (-1, 3)), np.reshape(dragged["X"], (-1, 3))
    assert dragged["placement"] == [v] and np.linalg.norm(Q[1] - V[hm[1]]) > 0.02 * diag
    np.testing.assert_array_equal(np.delete(Q, 1, axis=0), np.delete(V[hm], 1, axis=0))
    shipped = page_operator(op)  # B on its grid, as the fixed-P page ships it
    check_frame(shipped, X, Q, v, keep)
    check_surface(shipped, surfaced.surface, np.reshape(dragged["S"], (-1, 3)), X, Q, v, keep)  # the user's surface
    assert np.abs(X - python_frame(op, Q, [v])[keep]).max() <= 1e-3 * diag  # the grid moves the frame little
    # Reset: the rest pose of the new placement, exact
    assert reset["placement"] == [v]
    np.testing.assert_array_equal(np.reshape(reset["Q"], (-1, 3)), V[hm])
    np.testing.assert_array_equal(np.reshape(reset["X"], (-1, 3)), V[keep])


@pytest.mark.browser
def test_page_3d_refuses_bad_rest_placements(op, bar, tmp_path):
    nominal = int(op.placement.nominal[0])
    with chromium_page() as page:
        box, keep = open_page(page, op, bar, tmp_path)
        assert len(keep) < op.n_vertices  # the boundary's vertices and the placement's only
        drag_handle(page, box, E, 0, -30.0, 25.0)  # deformed first: nothing may change
        before = page.evaluate(STATE_JS)
        page.locator("button.defop-rest-toggle").click()
        here = screen(page, box, keep, nominal)
        pointer_path(page, here, (here[0] + 0.0, box["y"] + 5.0))  # the canvas' top edge: no region vertex
        outside = page.evaluate(STATE_JS)
        pointer_path(page, here, screen(page, box, keep, op.handles[0]))  # onto a fixed handle's sphere
        onto = page.evaluate(STATE_JS)
        by_code = page.evaluate(f"() => {E}.setRest(0, {int(op.handles[1])})")
        coded = page.evaluate(STATE_JS)
        p = [float(t) for t in op.mesh.V[nominal]]
        short = page.evaluate(f"() => {E}.setRest(0, {p[:2]})")  # an x-y point on a 3D page
        shorted = page.evaluate(STATE_JS)
        long_ = page.evaluate(f"() => {E}.setRest(0, {p + [0.0]})")
        longed = page.evaluate(STATE_JS)
        nan = page.evaluate(f"() => {E}.setRest(0, [{p[0]}, NaN, {p[2]}])")
        naned = page.evaluate(STATE_JS)
        errors = page.errors
    assert not errors, errors
    assert before["placement"] == [nominal] and before["Q"] != np.asarray(op.mesh.V[op.handles[4:]]).ravel().tolist()
    for bad, words in (
        (outside, "the pointer is outside rest handle 0's placement region"),
        (onto, "cannot move onto handle 0"),
        (coded, "holds handle 1"),
        (shorted, "a rest position is 3 finite numbers"),
        (longed, "a rest position is 3 finite numbers"),
        (naned, "a rest position is 3 finite numbers"),
    ):
        assert words in bad["msg"] and bad["shown"], bad["msg"]
        for key in ("placement", "Q", "X", "handles"):
            assert bad[key] == before[key], key
    assert by_code is False and short is False and long_ is False and nan is False
