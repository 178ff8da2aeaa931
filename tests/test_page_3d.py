"""The standalone 3D page (issue 27, part 5): :func:`defop.editor.export.to_html` for a 3D operator.

- The page's evaluator (``makeOperator`` of ``defop/editor/static/defop_editor.js``, the one the 2D editor uses) is
  run in Node on a small trained tet bar and compared with ``DefOp.__call__`` at random Q (hypothesis), on the
  exact and the compressed factors: handles exact (Prop. 2) and rest pose exact (8b) up to the float32 storage of
  W_F, with the bound of :func:`_float32_bound`.
- In headless Chromium (the machinery of tests/test_browser_editor.py) a handle is dragged with the mouse: the mesh
  moves, the handle's vertex lands on the pointer ray's intersection with the view plane through the handle
  (computed here in numpy from the page's camera matrices, independently of three.js' raycaster), the camera
  does not orbit while a handle is held, and Reset returns the rest pose to the last bit.
- A 3D operator with a 2D shape (and the reverse), or a picture on a 3D operator: a ValueError, and no file.
"""

from __future__ import annotations

import base64
import copy
import json
import subprocess

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference3d import box_tets  # tests/ is on sys.path (rootdir conftest)
from test_browser_editor import DRIVER, NODE, U32, _quiet, chromium_page, needs_node

import defop as dop
from defop.editor import export, payload


@pytest.fixture(scope="module")
def bar3():
    """The tet bar of tests/test_train_3d.py: 4 moving corners at x = 1 (shuffled), 4 fixed at x = 0."""
    V, T = box_tets((6, 1, 1), (1.0, 0.2, 0.2))
    left = np.flatnonzero(V[:, 0] == 0.0)
    right = np.random.default_rng(1).permutation(np.flatnonzero(V[:, 0] == 1.0))
    handles = np.concatenate([right, left])
    moving = np.arange(len(handles)) < len(right)
    regions = [{"kind": "ball", "radius": 0.08}] * len(right)
    return dop.Shape(name="bar3", mesh=dop.Mesh(V, T), handles=handles, moving=moving, regions=regions)


@pytest.fixture(scope="module")
def ops3(bar3):
    """TPS (r³ kernel) and linear operators, m a few samples above each basis' minimum (seconds on 2 cores)."""
    out = {}
    for kind in ("tps", "linear"):
        m = dop.training.min_samples(kind, bar3.n_moving, d=3) + 4
        out[kind], _ = dop.train(bar3, energy="sarap", basis=kind, m=m, seed=0, cache=False, n_jobs=1, progress=False)
    out["compressed"] = copy.deepcopy(out["tps"]).compress(rank=4)
    return out


def node_eval3(op, Qs, tmp_path):
    """The page's evaluator in Node on Qs (k,n,3): X (k,n_vertices,3), psi (k,|Ψ|), outside lists."""
    meta, data = payload.encode_payload(payload.defop_to_payload(op))
    spec = {
        "js": str(payload.JS_PATH),
        "meta": meta,
        "data": base64.b64encode(data).decode(),
        "Q": [np.asarray(Q, float).ravel().tolist() for Q in Qs],
    }
    path = tmp_path / "input3d.json"
    path.write_text(json.dumps(spec))
    res = subprocess.run([NODE, str(DRIVER), str(path)], capture_output=True, text=True, timeout=60, check=True)
    out = json.loads(res.stdout)
    return (
        np.array([o["X"] for o in out]).reshape(len(Qs), -1, 3),
        np.array([o["psi"] for o in out]),
        [o["outside"] for o in out],
    )


def _float32_bound(op, Q):
    """|D_js − D| ≤ u·Σ_j |δψ_j(Q)| |W_F,jc| per coordinate: W_F in float32, products in float64 (as in 2D)."""
    basis = op.handle_basis
    dpsi = np.abs(basis.delta_z(np.atleast_2d(basis.z(Q))))[0]
    WF = op.WF if op.factors is None else np.abs(op.factors[0]) @ np.abs(op.factors[1])
    return (4 * U32 * (dpsi @ np.abs(WF)) + 1e-12 * op.mesh.bbox_diagonal).reshape(-1, 3)


@needs_node
@pytest.mark.parametrize("kind", ["tps", "linear", "compressed"])
def test_page_evaluator_matches_defop_in_3d(ops3, kind, tmp_path_factory):
    op = ops3[kind]
    diag = op.mesh.bbox_diagonal
    tmp = tmp_path_factory.mktemp(kind)
    moving = op.handles[op.moving]

    @settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.lists(st.floats(-0.4, 0.4, allow_nan=False), min_size=3 * op.n_moving, max_size=3 * op.n_moving))
    def check(dQ):
        Q = op.P + np.reshape(dQ, (-1, 3)) * diag
        with _quiet():
            X_py = op(Q)
        X_js, psi_js, _ = node_eval3(op, [Q], tmp)
        np.testing.assert_allclose(psi_js[0], op.psi(Q), rtol=1e-12, atol=1e-12 * np.abs(op.psi(Q)).max())
        bound = _float32_bound(op, Q)
        # the page stores W_F (or the factors) in float32 and sums in float64; Python's compressed path sums the
        # float32 factors in float32: both within the bound
        assert np.all(np.abs(X_js[0] - X_py) <= bound), np.abs(X_js[0] - X_py).max() / diag
        assert np.all(np.abs(X_js[0][moving] - Q) <= 1e-12 * diag), "handles not exact (Prop. 2)"

    check()
    X_rest, _, outside = node_eval3(op, [op.P], tmp)
    np.testing.assert_array_equal(X_rest[0], op.mesh.V)  # (8b): δψ(P) = 0 bit for bit
    assert outside == [[]]


def test_payload_in_3d_is_the_boundary_surface_and_r3_kernel(ops3, bar3):
    op = ops3["tps"]
    p = payload.defop_to_payload(op)
    assert p["d"] == 3 and p["kernel"] == "r3" and op.handle_basis.kernel == "r3"
    np.testing.assert_array_equal(p["F"], bar3.mesh.boundary_facets)
    assert p["F"].shape[1] == 3 and p["V"].shape == (bar3.mesh.n_vertices, 3)
    balls = payload.region_balls(bar3.P_moving, bar3.regions)
    assert [b[0][3] for b in balls] == [0.08] * 4
    np.testing.assert_array_equal(np.array([b[0][:3] for b in balls]), bar3.P_moving)


def test_extrapolation_warning_in_node(ops3, bar3, tmp_path):
    """The page flags a handle beyond EXTRAPOLATION_FACTOR times its farthest training sample (the operator's
    rule), whatever ball is drawn."""
    op = ops3["tps"]
    reach = dop.operator.defop.training_reach(op.P, op.train_samples)
    Q = bar3.P_moving.copy()
    Q[2] += [0.0, 1.4 * reach[2], 0.0]  # inside 1.5x the reach
    Q2 = Q.copy()
    Q2[1] += [0.0, 0.0, 1.6 * reach[1]]  # beyond
    meta, data = payload.encode_payload(payload.defop_to_payload(op, payload.region_balls(bar3.P_moving, bar3.regions)))
    spec = {
        "js": str(payload.JS_PATH),
        "meta": meta,
        "data": base64.b64encode(data).decode(),
        "Q": [Q.ravel().tolist(), Q2.ravel().tolist()],
    }
    (tmp_path / "in.json").write_text(json.dumps(spec))
    if not NODE or subprocess.run([NODE, "--version"], capture_output=True).returncode:
        pytest.skip("no node")
    res = subprocess.run(
        [NODE, str(DRIVER), str(tmp_path / "in.json")], capture_output=True, text=True, timeout=60, check=True
    )
    assert [o["outside"] for o in json.loads(res.stdout)] == [[], [1]]


def test_dimension_mismatch_is_a_clear_error(ops3, bar3, tmp_path):
    flat = dop.shapes.load("bar")
    op2, _ = dop.train(
        flat,
        basis="linear",
        m=dop.training.min_samples("linear", flat.n_moving) + 2,
        progress=False,
        n_jobs=1,
        rounds=1,
    )
    with pytest.raises(ValueError, match="shape must be a 3D shape for this 3D operator, got the 2D shape"):
        export.to_html(ops3["tps"], tmp_path / "a.html", shape=flat)
    with pytest.raises(ValueError, match="shape must be a 2D shape for this 2D operator, got the 3D shape"):
        export.to_html(op2, tmp_path / "b.html", shape=bar3)
    with pytest.raises(ValueError, match="image and image_frame are for 2D operators"):
        export.to_html(ops3["tps"], tmp_path / "c.html", image=np.zeros((4, 4)), image_frame=np.zeros((8, 2)))
    assert not list(tmp_path.iterdir()), "a failed call leaves no file"


def test_vendored_three_is_pinned_and_licensed():
    import hashlib

    for name, digest in export.THREE_FILES.items():
        assert hashlib.sha256((export.THREE_DIR / name).read_bytes()).hexdigest() == digest
    licence = (export.THREE_DIR / "LICENSE").read_text()
    assert "The MIT License" in licence and "three.js authors" in licence
    readme = (export.THREE_DIR / "README.md").read_text()
    assert export.THREE_VERSION in readme and all(d in readme for d in export.THREE_FILES.values())


def _ray_plane(cam, u, v, point, normal):
    """Where the pointer ray at CSS pixel (u, v) meets the plane through ``point`` normal to ``normal``: numpy,
    from the camera's world matrix and inverse projection (column-major, as three.js stores them)."""
    M = np.array(cam["matrixWorld"]).reshape(4, 4).T
    Pinv = np.array(cam["projectionMatrixInverse"]).reshape(4, 4).T
    ndc = np.array([2 * u / cam["width"] - 1, 1 - 2 * v / cam["height"], 0.5, 1.0])
    view = Pinv @ ndc
    world = M @ (view / view[3])
    origin = M[:3, 3]
    direction = world[:3] - origin
    t = normal @ (point - origin) / (normal @ direction)
    return origin + t * direction


def drag_handle(page, box, e, i, du, dv, steps=5):
    """Drag moving handle i by (du, dv) CSS pixels, ending on whole pixels; returns what the test checks."""
    u, v = page.evaluate(f"() => {e}.handleScreen({i})")
    before = page.evaluate(f"() => ({{Q: Array.from({e}.st.Q), cam: {e}.cameraState()}})")
    page.mouse.move(box["x"] + u, box["y"] + v)
    page.mouse.down()
    u1, v1 = round(u + du), round(v + dv)  # whole pixels: the pointer event's position, exactly
    for t in np.linspace(1.0 / steps, 1.0, steps):
        page.mouse.move(box["x"] + u + (u1 - u) * t, box["y"] + v + (v1 - v) * t)
        page.wait_for_timeout(30)
    held = page.evaluate(f"() => ({{active: {e}.st.active, orbit: {e}.controls.enabled, plane: {e}.dragPlane}})")
    page.mouse.up()
    after = page.evaluate(
        f"() => ({{Q: Array.from({e}.st.Q), X: Array.from({e}.st.X), cam: {e}.cameraState(),"
        f" orbit: {e}.controls.enabled}})"
    )
    return {"u1": u1, "v1": v1, "before": before, "held": held, "after": after}


@pytest.mark.browser
def test_page_3d_drag_in_chromium(ops3, bar3, tmp_path):
    op = ops3["tps"]
    diag = op.mesh.bbox_diagonal
    moving = op.handles[op.moving]
    path = export.to_html(op, tmp_path / "bar3.html", shape=bar3)
    shipped = copy.deepcopy(op).set_factors(payload.page_factors(op))  # the page's operator: compressed by default
    rng = np.random.default_rng(5)  # which handle, and where to: varied, reproducibly
    drags = [(int(rng.integers(op.n_moving)), *(rng.choice([-1, 1], 2) * rng.uniform(25, 60, 2))) for _ in range(3)]
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        e = "window.defopEditor"
        X0 = np.array(page.evaluate(f"() => Array.from({e}.st.X)")).reshape(-1, 3)
        box = page.locator("canvas.defop-canvas").bounding_box()
        results = [drag_handle(page, box, e, i, du, dv) for i, du, dv in drags]
        page.screenshot(path="/tmp/defop_page_3d_drag.png")
        page.locator("button.defop-reset").click()
        rest = page.evaluate(f"() => ({{Q: Array.from({e}.st.Q), X: Array.from({e}.st.X)}})")
        # a drag on empty canvas orbits the camera
        cam0 = page.evaluate(f"() => {e}.cameraState()")
        page.mouse.move(box["x"] + 20, box["y"] + 20)
        page.mouse.down()
        page.mouse.move(box["x"] + 120, box["y"] + 60, steps=5)
        page.mouse.up()
        cam2 = page.evaluate(f"() => {e}.cameraState()")
        errors, requests = page.errors, page.requests
    assert not errors, errors
    assert all(url.startswith(("file:", "data:", "about:")) for url in requests), requests  # offline
    for (i, _, _), r in zip(drags, results, strict=True):
        held, before, after = r["held"], r["before"], r["after"]
        assert held["active"] == i and held["orbit"] is False, held  # orbit disabled while the handle is held
        assert after["orbit"] is True
        assert after["cam"]["matrixWorld"] == before["cam"]["matrixWorld"], "the camera moved during a handle drag"
        # the view plane: through the handle's position at pointerdown, normal to the viewing direction
        M = np.array(before["cam"]["matrixWorld"]).reshape(4, 4).T
        normal = -M[:3, 2] / np.linalg.norm(M[:3, 2])
        np.testing.assert_allclose(held["plane"]["normal"], normal, atol=1e-12)
        start = np.array(before["Q"]).reshape(-1, 3)
        target = _ray_plane(before["cam"], r["u1"], r["v1"], start[i], normal)
        Q = np.array(after["Q"]).reshape(-1, 3)
        X = np.array(after["X"]).reshape(-1, 3)
        np.testing.assert_allclose(Q[i], target, atol=1e-9 * diag)  # the handle is the cursor's target in 3D
        assert abs(normal @ (Q[i] - start[i])) <= 1e-9 * diag  # moved within the view plane
        assert np.linalg.norm(Q[i] - start[i]) > 0.02 * diag
        np.testing.assert_array_equal(np.delete(Q, i, axis=0), np.delete(start, i, axis=0))  # the others stay
        assert np.all(np.abs(X[moving] - Q) <= 1e-12 * diag), "the dragged vertices are not exactly on target"
        with _quiet():
            assert np.all(np.abs(X - shipped(Q)) <= _float32_bound(shipped, Q)), "the page's mesh is not op(Q)"
    assert np.max(np.linalg.norm(X - X0, axis=1)) > 0.05 * diag, "the mesh did not move"
    np.testing.assert_array_equal(np.array(rest["Q"]).reshape(-1, 3), op.P)
    np.testing.assert_array_equal(np.array(rest["X"]).reshape(-1, 3), op.mesh.V)  # reset: the rest pose, exact
    assert cam2["matrixWorld"] != cam0["matrixWorld"], "dragging empty canvas orbits"


def test_page_3d_is_one_inline_script_whatever_the_title(ops3, bar3, tmp_path):
    title = "</script><script>alert(1)</script><!-- bar & <b>"
    text = export.to_html(ops3["tps"], tmp_path / "t.html", shape=bar3, title=title).read_text()
    low = text.lower()
    assert low.count("</script") == 1 and low.count("<script") == 1 and "<!--" not in low
    assert "<h1>&lt;/script&gt;&lt;script&gt;alert(1)&lt;/script&gt;&lt;!-- bar &amp; &lt;b&gt;</h1>" in text
    assert "http://" not in low.split("<script", 1)[0] and "https://" not in low.split("<script", 1)[0]


def test_the_2d_editors_name_a_3d_shape(ops3, bar3):
    from defop.editor import browser
    from defop.editor.state import EditorState

    ops = {"tps": ops3["tps"]}
    said = "shape must be a 2D shape for the editor .* got the 3D shape 'bar3'.*to_html"
    for make in (lambda: EditorState(bar3, ops), lambda: browser.BrowserEditor(bar3, ops)):
        with pytest.raises(ValueError, match=said):
            make()
