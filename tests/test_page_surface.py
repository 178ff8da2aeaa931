"""The 3D page deforms the user's surface: :func:`defop.editor.payload.surface_payload` and ``makeSurface`` of
``defop/editor/static/defop_solid.js``.

A surface finer than the tetrahedra (the tet bar's boundary, each triangle split in four, the new vertices pushed
a little inside) is embedded in them (:class:`~defop.geometry.volumetric.surface.EmbeddedSurface`); its corners
are the bar's corners, so the moving handles lie on the surface. Under a drag the handle's surface vertex is
exactly on its target: in float64 Python (``EmbeddedSurface.deform`` of ``op(Q)``, within 1e-12 of the diagonal),
in the page's evaluator in Node and in Chromium (the page evaluates the surface in float64 from float32
barycentric coordinates whose fourth is 1 minus the others: a one-hot coordinate is exact). The rest of the surface
follows the piecewise-linear map of the tetrahedra within the float32 rounding of its coordinates. Without a
surface the page draws the boundary facets, and without WebGL it says so in words.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_browser_editor import chromium_page, needs_node, node_run
from test_page_3d import bar3, ops3  # noqa: F401  (fixtures)

import defop as dop
from defop.editor import export, payload
from defop.geometry.volumetric.surface import EmbeddedSurface

SURFACE_DRIVER = payload.JS_PATH.parents[3] / "tests" / "js" / "eval_surface.mjs"


def split_surface(V, F, inward=0.02):
    """Each triangle of (V, F) split in four at its edge midpoints; the midpoints moved ``inward`` (a fraction of
    the distance) towards the centroid of V, so they lie strictly inside the solid; the old vertices stay."""
    E = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, inv = np.unique(E, axis=0, return_inverse=True)
    mid = V[edges].mean(axis=1)
    mid += inward * (V.mean(axis=0) - mid)
    m = len(V) + inv.reshape(-1, 3)  # the midpoints of edges (a,b), (b,c), (c,a)
    a, b, c = F.T
    Fs = np.concatenate(
        [
            np.column_stack([a, m[:, 0], m[:, 2]]),
            np.column_stack([m[:, 0], b, m[:, 1]]),
            np.column_stack([m[:, 2], m[:, 1], c]),
            m,
        ]
    )
    return np.vstack([V, mid]), Fs


@pytest.fixture(scope="module")
def surfaced(bar3):  # noqa: F811
    """The bar with its own surface: the boundary's vertices (renumbered) and midpoints, 4x the triangles."""
    B = bar3.mesh.boundary_facets
    used = np.unique(B)
    renum = np.full(bar3.mesh.n_vertices, -1)
    renum[used] = np.arange(len(used))
    Vs, Fs = split_surface(bar3.mesh.V[used], renum[B])
    surface = EmbeddedSurface.embed(bar3.mesh, Vs, Fs)
    shape = dop.Shape(
        name="bar3s",
        mesh=bar3.mesh,
        handles=bar3.handles,
        moving=bar3.moving,
        regions=bar3.regions,
        surface=surface,
    )
    on_surface = renum[bar3.handles[bar3.moving]]  # the surface vertex of each moving handle
    assert np.all(on_surface >= 0)
    np.testing.assert_array_equal(Vs[on_surface], bar3.P_moving)
    return shape, surface, on_surface


def _targets(op, seed, k=3, scale=0.3):
    rng = np.random.default_rng(seed)
    return [op.P + scale * op.mesh.bbox_diagonal * rng.uniform(-1, 1, op.P.shape) for _ in range(k)]


def test_python_surface_puts_a_handle_on_its_target(ops3, surfaced):  # noqa: F811
    op = ops3["tps"]
    _, surface, on_surface = surfaced
    diag = op.mesh.bbox_diagonal
    for Q in _targets(op, 11):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
            S = surface.deform(op(Q))
        assert np.abs(S[on_surface] - Q).max() <= 1e-12 * diag
    np.testing.assert_allclose(surface.deform(op.mesh.V), surface.V, atol=1e-12 * diag)  # rest: the surface


def _node_surface(op, shape, Qs, tmp_path):
    p = payload.defop_to_payload(op)
    p.update(payload.surface_payload(shape.surface, op.n_vertices))
    return node_run(SURFACE_DRIVER, p, Qs, tmp_path)


def float32_bary_bound(surface, X):
    """|S_page − S| per surface vertex: b_1..b_3 rounded to float32 (relative u), b_0 = 1 − Σ in float64, so the
    error is at most 2u Σ_k |b_k| |X_k − X_0| (and the float64 sums, far below)."""
    T = surface.tets[surface.elements]
    D = np.linalg.norm(X[T[:, 1:]] - X[T[:, :1]], axis=-1)  # (k, 3)
    return 2 * 2.0**-24 * (np.abs(surface.bary[:, 1:]) * D).sum(axis=1) + 1e-13


@needs_node
def test_page_surface_in_node(ops3, surfaced, tmp_path):  # noqa: F811
    op = ops3["tps"]
    shape, surface, on_surface = surfaced
    Qs = [op.P, *_targets(op, 12)]
    out = _node_surface(op, shape, Qs, tmp_path)
    diag = op.mesh.bbox_diagonal
    for Q, o in zip(Qs, out, strict=True):
        assert o["embedded"]
        X = np.array(o["X"]).reshape(-1, 3)
        S = np.array(o["S"]).reshape(-1, 3)
        np.testing.assert_array_equal(S[on_surface], Q)  # the handle's surface vertex: exactly the target
        err = np.linalg.norm(S - surface.deform(X), axis=1)
        assert np.all(err <= float32_bary_bound(surface, X)), err.max() / diag
    # without a surface: the boundary facets on the vertices themselves
    p = payload.defop_to_payload(op)
    assert "surface_F" not in p


@pytest.mark.browser
def test_page_draws_and_drags_the_embedded_surface(ops3, surfaced, tmp_path):  # noqa: F811
    op = ops3["tps"]
    shape, surface, on_surface = surfaced
    path = export.to_html(op, tmp_path / "surface.html", shape=shape)
    text = path.read_text()
    assert "surface, carried by the tetrahedra</span>" in text  # the legend names what is drawn
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        e = "window.defopEditor"
        drawn = page.evaluate(f"() => ({{n: {e}.scene.positions.length, tri: {e}.st.surfaceTriangles}})")
        box = page.locator("canvas.defop-canvas").bounding_box()
        u, v = page.evaluate(f"() => {e}.handleScreen(1)")
        page.mouse.move(box["x"] + u, box["y"] + v)
        page.mouse.down()
        page.mouse.move(box["x"] + u + 40, box["y"] + v - 30, steps=5)
        page.wait_for_timeout(100)
        page.mouse.up()
        st = page.evaluate(f"() => ({{Q: Array.from({e}.st.Q), X: Array.from({e}.st.X), S: Array.from({e}.st.S)}})")
        normals = page.evaluate(f"() => {e}.scene.geometry.attributes.normal.count")
        page.screenshot(path="/tmp/defop_page_surface.png")
        errors = page.errors
    assert not errors, errors
    assert drawn == {"n": 3 * len(surface.V), "tri": len(surface.F)}
    assert normals == len(surface.V)  # one normal per shared vertex: smooth shading
    Q = np.array(st["Q"]).reshape(-1, 3)
    X = np.array(st["X"]).reshape(-1, 3)
    S = np.array(st["S"]).reshape(-1, 3)
    assert np.linalg.norm(Q[1] - op.P[1]) > 0.02 * op.mesh.bbox_diagonal, "the handle did not move"
    np.testing.assert_array_equal(S[on_surface], Q)  # exactly on target, in the page
    assert np.all(np.linalg.norm(S - surface.deform(X), axis=1) <= float32_bary_bound(surface, X))


@pytest.mark.browser
def test_page_without_webgl_says_so(ops3, surfaced, tmp_path):  # noqa: F811
    shape = surfaced[0]
    path = export.to_html(ops3["tps"], tmp_path / "nowebgl.html", shape=shape)
    with chromium_page(["--disable-3d-apis", "--disable-webgl"]) as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        note = page.locator(".defop-nowebgl")
        shown = note.is_visible()
        said = note.text_content()
        state = page.evaluate("() => ({webgl: window.defopEditor.webgl, canvas: !!document.querySelector('canvas')})")
        errors = page.errors
    assert not errors, errors
    assert shown and "WebGL" in said and "another browser" in said, said
    assert state == {"webgl": False, "canvas": False}


def test_surface_of_other_tetrahedra_is_a_clear_error(surfaced):
    surface = surfaced[1]
    with pytest.raises(ValueError, match="embedded in other tetrahedra"):
        payload.surface_payload(surface, n_vertices=4)
