"""The in-page editor (issue #18): its JavaScript evaluation, the editor state and the standalone page.

- The page's own module ``defop/editor/static/defop_editor.js`` is run in Node and compared with ``DefOp.__call__``
  at random Q (hypothesis) for every handle basis; handles and rest pose are exact up to the float32
  storage of the factors, with the bound stated in :func:`_float32_bound`.
- :class:`defop.editor.state.EditorState` is driven through its public API only.
- The standalone page of :func:`defop.editor.export.to_html` is dragged in headless Chromium (Playwright).
- A picture on the mesh (:func:`defop.editor.payload.image_payload`): validated in Python, textured in WebGL in
  Chromium, where the rendered colours are compared with the picture before and after a mouse drag.
"""

from __future__ import annotations

import base64
import contextlib
import copy
import json
import os
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.editor import browser, export, payload
from defop.editor.state import EditorState, ground_truth_text, inside_polygon

ROOT = Path(__file__).resolve().parents[1]
DRIVER = ROOT / "tests" / "js" / "eval_operator.mjs"
NODE = shutil.which("node") or "/usr/bin/node"
CHROMIUM = os.environ.get("DEFOP_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
KINDS = ("linear", "quadratic", "cubic", "tps")
U32 = 2.0**-24  # unit round-off of float32 storage
SHAPE = "u_shape"  # 2 moving + 4 fixed handles, 795 vertices: every basis trains in seconds

needs_node = pytest.mark.skipif(not os.access(NODE, os.X_OK), reason=f"no node at {NODE}")


@pytest.fixture(scope="module")
def shape():
    return dop.shapes.load(SHAPE)


@pytest.fixture(scope="module")
def operators(shape):
    """Small operators (fast settings, cached under DEFOP_CACHE): m just above each basis' minimum."""
    ops = {}
    for kind in KINDS:
        m = 20 if kind == "tps" else dop.operator.handle_bases.basis_size(kind, shape.n_moving) + 5
        ops[kind], _ = dop.train(shape, basis=kind, m=m, progress=False, n_jobs=1, rounds=1)
    return ops


def node_run(driver, page_payload, Qs, tmp_path):
    """Run a Node driver (tests/js/*.mjs) on the page's module with a payload and Qs (k,n,d): its parsed JSON."""
    meta, data = payload.encode_payload(page_payload)
    spec = {
        "js": str(payload.JS_PATH),
        "meta": meta,
        "data": base64.b64encode(data).decode(),
        "Q": [np.asarray(Q, float).ravel().tolist() for Q in Qs],
    }
    path = tmp_path / "input.json"
    path.write_text(json.dumps(spec))
    res = subprocess.run([NODE, str(driver), str(path)], capture_output=True, text=True, timeout=60, check=True)
    return json.loads(res.stdout)


def node_eval(op, Qs, tmp_path, regions=None):
    """Run the page's module in Node on Qs (k,n,2); returns X (k,n_vertices,2), psi (k,|Ψ|) and outside lists."""
    out = node_run(DRIVER, payload.defop_to_payload(op, regions), Qs, tmp_path)
    X = np.array([o["X"] for o in out]).reshape(len(Qs), -1, 2)
    return X, np.array([o["psi"] for o in out]), [o["outside"] for o in out]


def _float32_bound(op, Q):
    """|D_js − D| ≤ u·Σ_j |δψ_j(Q)| |W_F,jc| per coordinate ((★) of defop.operator.defop): W_F stored in float32
    (relative error ≤ u = 2^-24), products accumulated in float64 (their error is ~1e-16 relative, far below)."""
    basis = op.handle_basis
    dpsi = np.abs(basis.delta_z(np.atleast_2d(basis.z(Q))))[0]
    return (U32 * (dpsi @ np.abs(op._WF)) + 1e-12 * op.mesh.bbox_diagonal).reshape(-1, 2)


def _displacements(n):
    """Handle displacements up to 0.6 of the diagonal: inside and far outside the sampling regions."""
    return st.lists(st.floats(-0.6, 0.6, allow_nan=False), min_size=2 * n, max_size=2 * n).map(
        lambda v: np.reshape(v, (n, 2))
    )


# ---------------------------------------------------------------------------------------------- (a), (b)
@needs_node
@pytest.mark.parametrize("kind", KINDS)
def test_javascript_matches_defop_at_random_Q(operators, kind, tmp_path_factory):
    op = operators[kind]
    diag = op.mesh.bbox_diagonal
    tmp = tmp_path_factory.mktemp(kind)

    @settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(_displacements(op.n_moving))
    def check(dQ):
        Q = op.P + dQ * diag
        with _quiet():
            X_py = op(Q)
        X_js, psi_js, _ = node_eval(op, [Q], tmp)
        np.testing.assert_allclose(psi_js[0], op.psi(Q), rtol=1e-12, atol=1e-12 * np.abs(op.psi(Q)).max())
        err = np.max(np.linalg.norm(X_js[0] - X_py, axis=1))
        assert err <= 1e-5 * diag, f"{kind}: JS differs from DefOp by {err / diag:.2e} of the diagonal"
        moving = op.handles[op.moving]
        assert np.all(np.abs(X_js[0][moving] - Q) <= _float32_bound(op, Q)[moving]), "handles not exact (Prop. 2)"

    check()


@contextlib.contextmanager
def _quiet():
    """Far Q are tested on purpose: silence the operator's ExtrapolationWarning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        yield


@needs_node
@pytest.mark.parametrize("kind", KINDS)
def test_javascript_rest_pose_and_fixed_handles_exact(operators, kind, tmp_path):
    op = operators[kind]
    X_js, _, outside = node_eval(op, [op.P], tmp_path)
    bound = _float32_bound(op, op.P)
    assert np.all(np.abs(X_js[0] - op.mesh.V) <= bound), "rest pose not exact (8b)"
    fixed = op.handles[~op.moving]
    np.testing.assert_array_less(np.abs(X_js[0][fixed] - op.mesh.V[fixed]), bound[fixed] + 1e-300)
    assert outside == [[]]
    # the bound itself is tiny: float32 round-off relative to the diagonal
    assert bound.max() / op.mesh.bbox_diagonal < 1e-6


@needs_node
def test_javascript_compressed_factors_match(operators, tmp_path):
    op = copy.deepcopy(operators["tps"]).compress(rank=8)
    rng = np.random.default_rng(3)
    Qs = op.P + 0.2 * op.mesh.bbox_diagonal * rng.standard_normal((4, op.n_moving, 2))
    X_js, _, _ = node_eval(op, Qs, tmp_path)
    with _quiet():
        X_py = op(Qs)
    assert np.max(np.linalg.norm(X_js - X_py, axis=-1)) <= 1e-5 * op.mesh.bbox_diagonal


@needs_node
def test_javascript_extrapolation_matches_state(operators, shape, tmp_path):
    state = EditorState(shape, operators, basis="tps")
    rng = np.random.default_rng(0)
    r = shape.regions[0]["radius"]
    Qs = state.P + 0.8 * r * rng.standard_normal((12, state.P.shape[0], 2))
    polys = state.regions
    _, _, outside = node_eval(operators["tps"], Qs, tmp_path, regions=polys)
    assert [state.outside_regions(Q) for Q in Qs] == outside
    assert any(outside) and not all(outside)


def test_payload_round_trip(operators):
    p = payload.defop_to_payload(operators["cubic"])
    meta, data = payload.encode_payload(p)
    for name, a in meta["arrays"].items():
        assert a["offset"] % 8 == 0
        dt = {"f8": np.float64, "f4": np.float32, "i4": np.int32, "u1": np.uint8}[a["dtype"]]
        back = np.frombuffer(data, dt, a["length"], a["offset"]).reshape(a["shape"])
        np.testing.assert_array_equal(back, p[name])
    assert meta["scalars"]["size"] == operators["cubic"].handle_basis.size
    assert len(meta["arrays"]["parent"]["shape"]) == 1 and meta["arrays"]["parent"]["length"] == p["size"] - 1


# ---------------------------------------------------------------------------------------------- (c)
def test_state_handles_and_rest_pose(operators, shape):
    state = EditorState(shape, operators, basis="quadratic")
    np.testing.assert_array_equal(state.Q, shape.P_moving)
    np.testing.assert_allclose(state.X, shape.mesh.V, atol=1e-9 * state.diag)
    q = state.P[1] + [0.05 * state.diag, -0.03 * state.diag]
    state.set_handle(1, q)
    np.testing.assert_allclose(state.X[shape.moving_handles[1]], q, atol=1e-9 * state.diag)
    np.testing.assert_allclose(state.X[shape.fixed_handles], shape.mesh.V[shape.fixed_handles], atol=1e-9)
    state.set_basis("tps")
    assert state.kind == "tps" and state.operator is operators["tps"]
    np.testing.assert_allclose(state.X[shape.moving_handles[1]], q, atol=1e-9 * state.diag)
    state.reset()
    np.testing.assert_array_equal(state.Q, state.P)


def test_state_rejects_bad_input(operators, shape):
    state = EditorState(shape, operators)
    with pytest.raises(ValueError, match="out of range"):
        state.set_handle(5, [0, 0])
    with pytest.raises(ValueError, match="NaN or infinite"):
        state.set_handle(0, [np.nan, 0])
    with pytest.raises(ValueError, match=r"handle index must be an integer, got 0\.5"):  # was truncated to 0
        state.set_handle(0.5, [0, 0])
    with pytest.raises(ValueError, match="Q must be an array of real numbers, got complex numbers"):
        state.set_Q(state.P + 1e-3j)  # the imaginary part was dropped with a ComplexWarning
    with pytest.raises(ValueError, match="q must be an array of real numbers, got complex numbers"):
        state.set_handle(0, [1j, 0])
    with pytest.raises(ValueError, match="Q must be an array of real numbers, got complex numbers"):
        shape.targets(state.P + 1e-3j)
    with pytest.raises(ValueError, match="shape"):
        state.set_Q(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="not offered"):
        state.set_basis("quartic")
    other = dop.shapes.load("bar")
    with pytest.raises(ValueError, match="trained on a mesh"):
        EditorState(other, {"tps": operators["tps"]})


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(i=st.integers(0, 1), dx=st.floats(-1, 1), dy=st.floats(-1, 1))
def test_state_pick_nearest_handle(operators, shape, i, dx, dy):
    state = EditorState(shape, operators)
    r = state.pick_radius * state.diag
    x, y = state.P[i] + 0.9 * r * np.array([dx, dy]) / max(1.0, np.hypot(dx, dy))
    d = np.hypot(*(state.P - [x, y]).T)
    assert state.pick(x, y) == int(np.argmin(d))
    assert state.pick(*(state.P[i] + [10 * state.diag, 0])) is None


def test_state_outside_regions_is_the_operators_rule(operators, shape):
    state = EditorState(shape, operators)
    assert state.outside_regions() == []
    reach = dop.operator.defop.training_reach(state.P, state.operator.train_samples)
    for t, out in ((0.9, []), (1.1, []), (1.45, []), (1.55, [0])):  # 1.5x the farthest training sample
        Q = state.P.copy()
        Q[0] += [t * reach[0] / np.sqrt(2), t * reach[0] / np.sqrt(2)]
        assert state.outside_regions(Q) == out
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    assert inside_polygon([0.5, 0.5], square) and not inside_polygon([1.5, 0.5], square)


def test_state_trains_missing_bases_on_first_use(operators, shape):
    calls = []

    def trainer(shape_, kind):
        calls.append(kind)
        return operators[kind]

    state = EditorState(shape, {"tps": operators["tps"]}, trainer=trainer)
    assert calls == []
    state.set_basis("linear")
    state.set_basis("tps")
    state.set_basis("linear")
    assert calls == ["linear"]


def test_state_ground_truth(operators, shape):
    state = EditorState(shape, operators, basis="tps", energy="sarap")
    state.set_ground_truth(True)
    assert state.gt_error["rms"] < 1e-6  # at rest the ground truth is the rest pose
    q = state.P[0] + [0.04 * state.diag, 0.02 * state.diag]
    state.set_handle(0, q)
    assert state.gt_result.converged
    np.testing.assert_allclose(state.X_gt[shape.moving_handles[0]], q, atol=1e-8 * state.diag)
    np.testing.assert_array_equal(state.Q_gt, state.Q)
    e = state.gt_error
    assert 0 < e["rms"] <= e["max"] < 0.05 and e["flips_gt"] == 0
    assert "error rms" in ground_truth_text(state)
    state.set_ground_truth(False)
    assert state.gt_error is None and ground_truth_text(state) == ""


def test_widget_kernel_side(operators, shape):
    """What the page sends (q on release, basis, ground truth) reaches the state; what Python sends back."""
    editor = browser.BrowserEditor(shape, dict(operators), basis="tps")
    meta = editor.payload_meta
    assert meta["scalars"]["kind"] == "tps" and meta["scalars"]["kinds"] == list(KINDS)
    Q = editor.Q + [[0.02, 0.01], [0.0, 0.0]]
    editor.q = Q.ravel().tolist()  # as the page does on release
    np.testing.assert_array_equal(editor.Q, Q)
    np.testing.assert_allclose(editor.state.X[shape.moving_handles], Q, atol=1e-9)
    editor.ground_truth = True
    X_gt = np.frombuffer(editor.gt_data, np.float32).reshape(-1, 2)
    np.testing.assert_allclose(X_gt, editor.state.X_gt, atol=1e-6)
    assert "error rms" in editor.gt_meta["text"]
    editor.basis = "linear"
    assert editor.payload_meta["scalars"]["size"] == operators["linear"].handle_basis.size
    np.testing.assert_array_equal(editor.Q, Q)  # switching basis keeps Q
    editor.set_Q(editor.state.P)
    assert editor.q == editor.state.P.ravel().tolist()


def test_widget_switches_shape(operators, shape):
    editor = browser.BrowserEditor(shape, dict(operators), basis="tps", m=20, shapes=["u_shape", "bar"])
    assert editor.payload_meta["scalars"]["shapes"] == ["u_shape", "bar"]
    editor.shape_name = "bar"  # as the page's shape menu does: trains the bar's operator in the kernel
    assert editor.state.shape.name == "bar"
    assert editor.payload_meta["scalars"]["n_vertices"] == editor.state.mesh.n_vertices != shape.mesh.n_vertices
    np.testing.assert_array_equal(editor.Q, editor.state.shape.P_moving)


def test_javascript_is_package_data():
    import importlib.resources
    import tomllib

    assert importlib.resources.files("defop").joinpath("editor/static/defop_editor.js").is_file()
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["defop"]
    assert "editor/static/*.js" in data and "scene/data/*.json" in data


# ---------------------------------------------------------------------------------------------- (d)
@contextlib.contextmanager
def chromium_page(extra_args=(), viewport=(1280, 720)):
    """A page of headless Debian Chromium driven by Playwright (skips when either is missing).

    The page records its requests and uncaught errors in ``page.requests`` and ``page.errors``.
    """
    sync_api = pytest.importorskip("playwright.sync_api", reason="the Python package playwright is not installed")
    if not (os.path.isfile(CHROMIUM) and os.access(CHROMIUM, os.X_OK)):
        pytest.skip(f"no Chromium at {CHROMIUM}")
    from test_browser import CHROMIUM_ARGS

    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS + list(extra_args))
        try:
            page = chromium.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            page.requests, page.errors = [], []
            page.on("request", lambda r: page.requests.append(r.url))
            page.on("pageerror", lambda e: page.errors.append(str(e)))
            yield page
        finally:
            chromium.close()


def mouse_drag(page, editor, dx, dy, steps=10):
    """Drag moving handle 0 of the page's editor (a JS expression) by (dx, dy) screen pixels with the mouse.

    Returns
    -------
    end : (2,) numpy array
        Where the pointer was released, in the mesh's coordinates (the page's view).
    """
    box = page.locator("canvas.defop-canvas").bounding_box()
    u, v = page.evaluate(f"() => {editor}.handleScreen(0)")
    x0, y0 = box["x"] + u, box["y"] + v
    page.mouse.move(x0, y0)
    page.mouse.down()
    for t in np.linspace(0.1, 1.0, steps):
        page.mouse.move(x0 + dx * t, y0 + dy * t)
        page.wait_for_timeout(20)
    page.mouse.up()
    return np.array(page.evaluate(f"([u, v]) => {editor}.st.view.toData(u, v)", [u + dx, v + dy]))


@pytest.mark.browser
@pytest.mark.parametrize("webgl", [True, False], ids=["webgl", "canvas2d"])
def test_standalone_page_drag_in_chromium(operators, shape, tmp_path, webgl):
    """The page drags offline; without WebGL (``--disable-3d-apis``) it falls back to the 2D canvas."""
    op = operators["tps"]
    page_path = export.to_html(op, tmp_path / "u_shape.html", shape=shape)
    text = page_path.read_text()
    assert "http://" not in text and "https://" not in text  # nothing to fetch: works offline
    with chromium_page([] if webgl else ["--disable-3d-apis"]) as page:
        page.goto(page_path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        X0 = np.array(page.evaluate("() => Array.from(window.defopEditor.st.X)")).reshape(-1, 2)
        end = mouse_drag(page, "window.defopEditor", 40, -30)
        state = page.evaluate(
            "() => { const e = window.defopEditor; return {Q: Array.from(e.st.Q), X: Array.from(e.st.X),"
            " warn: e.ui.warn.textContent, gl: e.st.gl !== null} }"
        )
        far = page.evaluate(  # a handle beyond 1.5x its farthest training sample: the readout warns
            "() => { const e = window.defopEditor; e.st.Q[2] += 0.3; e.evaluate(); return e.ui.warn.textContent; }"
        )
        page.screenshot(path=f"/tmp/defop_standalone_drag_{'webgl' if webgl else 'canvas2d'}.png")
        errors, requests = page.errors, page.requests
    state["end"] = end
    assert not errors, errors
    assert far.startswith("handle 1 beyond 1.5× its farthest training sample"), far
    assert state["warn"] == ""
    if not webgl:
        assert not state["gl"]  # the 2D fallback drew this page
    assert all(url.startswith(("file:", "data:", "about:")) for url in requests), requests
    Q = np.array(state["Q"]).reshape(-1, 2)
    X = np.array(state["X"]).reshape(-1, 2)
    np.testing.assert_allclose(Q[0], state["end"], atol=1e-9)  # the handle is where the pointer was released
    assert Q[0, 0] > op.P[0, 0] and Q[0, 1] > op.P[0, 1]  # screen right/up = data +x/+y
    np.testing.assert_array_equal(Q[1], op.P[1])
    moving = op.handles[op.moving]
    np.testing.assert_allclose(X[moving], Q, atol=1e-6 * op.mesh.bbox_diagonal)  # the mesh follows the handle
    assert np.max(np.linalg.norm(X - X0, axis=1)) > 0.01 * op.mesh.bbox_diagonal
    shipped = copy.deepcopy(op).set_factors(payload.page_factors(op))  # the page's operator: compressed by default
    with _quiet():
        np.testing.assert_allclose(X, shipped(Q), atol=1e-5 * op.mesh.bbox_diagonal)


# ---------------------------------------------------------------------------------------------- (e)
_WIDGET_NOTEBOOK = [
    "import json\nimport defop as dop\nfrom defop.editor.browser import BrowserEditor",
    "editor = BrowserEditor('u_shape', basis='tps', kinds=('tps', 'linear'), m=20)\n"
    "editor.observe(lambda c: open('q.json', 'w').write(json.dumps(c['new'])), names='q')\neditor",
]


@pytest.fixture
def widget_lab(tmp_path, request):
    """JupyterLab serving a notebook that shows a BrowserEditor (the pattern of tests/test_browser.py).

    The notebook's cells are ``_WIDGET_NOTEBOOK`` unless the test passes others (indirect parametrisation)."""
    import sys

    import nbformat
    from test_browser import TOKEN, _free_port, _wait_for_server

    root = tmp_path / "notebooks"
    root.mkdir()
    nb = nbformat.v4.new_notebook(
        cells=[nbformat.v4.new_code_cell(src) for src in getattr(request, "param", _WIDGET_NOTEBOOK)],
        metadata={"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
    )
    nbformat.write(nb, root / "editor.ipynb")
    settings = tmp_path / "lab-settings" / "@jupyterlab" / "apputils-extension"
    settings.mkdir(parents=True)
    (settings / "notification.jupyterlab-settings").write_text('{"fetchNews": "false", "checkForUpdates": false}')
    env = dict(
        os.environ,
        DEFOP_CACHE=str(tmp_path / "cache"),
        DEFOP_N_JOBS="1",
        JUPYTER_CONFIG_DIR=str(tmp_path / "jc"),
        JUPYTER_RUNTIME_DIR=str(tmp_path / "jr"),
        JUPYTERLAB_SETTINGS_DIR=str(tmp_path / "lab-settings"),
        JUPYTERLAB_WORKSPACES_DIR=str(tmp_path / "lw"),
        IPYTHONDIR=str(tmp_path / "ipython"),
        PYTHONPATH=str(ROOT),
    )
    port = _free_port()
    log = open(tmp_path / "lab.log", "w")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "jupyterlab",
            "--ServerApp.ip=127.0.0.1",
            f"--ServerApp.port={port}",
            "--ServerApp.port_retries=0",
            f"--IdentityProvider.token={TOKEN}",
            "--no-browser",
            "--allow-root",
            f"--ServerApp.root_dir={root}",
            "--LabApp.expose_app_in_browser=True",
        ],
        env=env,
        cwd=root,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        _wait_for_server(url, proc)
        yield {"url": url, "root": root, "tmp": tmp_path}
    finally:
        from test_browser import stop_server

        stop_server(proc, log)


def open_lab_notebook(page, widget_lab):
    """Open the widget_lab notebook in JupyterLab, run all its cells, and return the editor's canvas locator."""
    from test_browser import TOKEN, run_all_cells

    assert not run_all_cells(page, f"{widget_lab['url']}/lab/tree/editor.ipynb?token={TOKEN}", 240_000)
    canvas = page.locator(".defop-editor canvas.defop-canvas").first
    canvas.wait_for(state="visible")
    canvas.scroll_into_view_if_needed()
    return canvas


@pytest.mark.browser
def test_anywidget_drag_in_jupyterlab(widget_lab):
    from test_browser import _KERNEL_IDLE

    with chromium_page(viewport=(1400, 1000)) as page:
        canvas = open_lab_notebook(page, widget_lab)
        page.wait_for_timeout(500)
        editor = "document.querySelector('.defop-editor').parentNode.defopEditor"
        X0 = np.array(page.evaluate(f"() => Array.from({editor}.st.X)")).reshape(-1, 2)
        box = canvas.bounding_box()
        u, v = page.evaluate(f"() => {editor}.handleScreen(0)")
        x0, y0 = box["x"] + u, box["y"] + v
        page.mouse.move(x0, y0)
        page.mouse.down()
        for t in np.linspace(0.1, 1.0, 10):
            page.mouse.move(x0 + 40 * t, y0 - 30 * t)
            page.wait_for_timeout(30)
        page.mouse.up()
        end = page.evaluate(f"([u, v]) => {editor}.st.view.toData(u, v)", [u + 40, v - 30])
        X1 = np.array(page.evaluate(f"() => Array.from({editor}.st.X)")).reshape(-1, 2)
        q_file = widget_lab["root"] / "q.json"
        page.wait_for_function(_KERNEL_IDLE, timeout=30_000)
        for _ in range(100):
            if q_file.exists():
                break
            page.wait_for_timeout(100)
        # the ground-truth overlay: solved in the kernel, drawn when it arrives, with its error
        page.locator(".defop-editor input.defop-gt").first.check()
        page.wait_for_function(
            "() => document.querySelector('.defop-gt-readout').textContent.includes('error rms')", timeout=60_000
        )
        gt_text = page.locator(".defop-gt-readout").first.text_content()
        page.screenshot(path="/tmp/defop_anywidget_drag.png")
    diag = np.linalg.norm(np.ptp(X0, axis=0))
    assert np.max(np.linalg.norm(X1 - X0, axis=1)) > 0.01 * diag  # the mesh moved in the page
    Q_py = np.reshape(json.loads(q_file.read_text()), (-1, 2))  # Q came back to the kernel on release
    np.testing.assert_allclose(Q_py[0], end, atol=1e-9)
    np.testing.assert_allclose(X1[dop.shapes.load(SHAPE).moving_handles[0]], end, atol=1e-6 * diag)
    assert "flips" in gt_text and "NOT converged" not in gt_text, gt_text


# ---------------------------------------------------------------------------------------------- (f) a picture
def picture_for(mesh, width=300, margin=10):
    """A smooth colour field (no sharp edge, so a colour pins down a position) and a mesh → pixel map.

    Returns
    -------
    image : (H,width,3) float numpy array in [0.1, 0.9]
    to_pixels : callable
        (k,2) mesh coordinates → (k,2) pixels (x = column, y = row down): the mesh's bounding box scaled into
        the picture with ``margin`` pixels around it.
    """
    lo, hi = mesh.V.min(axis=0), mesh.V.max(axis=0)
    s = (width - 2 * margin) / (hi - lo)[0]
    H = int(np.ceil((hi - lo)[1] * s)) + 2 * margin

    def to_pixels(X):
        X = np.asarray(X, float)
        return np.column_stack([margin + (X[:, 0] - lo[0]) * s, H - margin - (X[:, 1] - lo[1]) * s])

    y, x = np.mgrid[0:H, 0:width].astype(float)
    image = np.stack(
        [0.5 + 0.4 * np.sin(x / 23), 0.5 + 0.4 * np.sin(y / 17 + 1), 0.5 + 0.4 * np.cos((x + y) / 31)], axis=-1
    )
    return image, to_pixels


def _png_array(data):
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(bytes(data))))


@settings(max_examples=12, deadline=None)
@given(
    layout=st.sampled_from([(), (3,), (4,), (1,)]),
    dtype=st.sampled_from(["uint8", "float32", "float64", "bool"]),
    h=st.integers(3, 40),
    w=st.integers(3, 40),
    seed=st.integers(0, 2**16),
)
def test_image_payload_png_round_trip(layout, dtype, h, w, seed):
    """Grey, RGB, RGBA and (H,W,1) pictures of every accepted dtype reach the page as the same 8-bit picture."""
    rng = np.random.default_rng(seed)
    img = rng.random((h, w, *layout))
    img = (
        (img > 0.5)
        if dtype == "bool"
        else (np.round(img * 255).astype(np.uint8) if dtype == "uint8" else img.astype(dtype))
    )
    V_px = rng.uniform(-0.5, [w - 0.5, h - 0.5], size=(7, 2))
    p = payload.image_payload(img, V_px)
    expected = dop.geometry.planar.outlines.load_image(img)
    back = _png_array(p["image_png"])
    assert back.shape == expected.shape and back.dtype == np.uint8
    np.testing.assert_array_equal(back, np.round(expected * 255).astype(np.uint8))
    assert p["image_size"] == [w, h]
    np.testing.assert_allclose(p["uv"] * [w, h] - 0.5, V_px, atol=1e-5 * max(w, h))  # float32 texture coordinates


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (np.zeros((0, 0, 3)), "too small"),
        (np.zeros((5,)), "must be"),
        (np.zeros((20, 20, 2)), "must be"),
        (np.full((20, 20, 3), np.nan), "NaN"),
        (np.zeros((20, 20), complex), "real numbers"),
        (np.full((20, 20), 1.5), r"\[0,1\]"),
        (np.zeros((20, payload.MAX_IMAGE_SIDE + 1)), "at most 4096 per side"),
    ],
    ids=["empty", "1d", "two-channels", "nan", "complex", "out-of-range", "too-large"],
)
def test_image_payload_rejects_bad_pictures(image, match):
    with pytest.raises(ValueError, match=match):
        payload.image_payload(image, np.zeros((3, 2)))


def test_image_frame_is_checked(operators, shape, monkeypatch):
    op = operators["tps"]
    image, to_pixels = picture_for(shape.mesh)
    with pytest.raises(ValueError, match=r"vertex \d+ maps to pixel .* outside the 300 x \d+ picture"):
        browser.BrowserEditor(shape, {"tps": op}, image=image, image_frame=lambda X: 1000 * X)  # a wrong frame
    with pytest.raises(ValueError, match="one pixel position per vertex"):
        browser.BrowserEditor(shape, {"tps": op}, image=image, image_frame=to_pixels(shape.mesh.V)[:-1])
    bad = to_pixels(shape.mesh.V)
    bad[7] = np.nan
    with pytest.raises(ValueError, match=r"NaN or infinite pixel position \(vertex 7\)"):
        export.to_html(op, "unused.html", image=image, image_frame=bad)
    with pytest.raises(ValueError, match="go together"):
        browser.BrowserEditor(shape, {"tps": op}, image=image)
    with pytest.raises(ValueError, match="go together"):
        export.to_html(op, "unused.html", image_frame=to_pixels)
    with pytest.raises(ValueError, match="either image or shapes"):
        browser.BrowserEditor(shape, {"tps": op}, image=image, image_frame=to_pixels, shapes=["u_shape", "bar"])
    monkeypatch.setattr(payload, "MAX_IMAGE_BYTES", 1000)
    with pytest.raises(ValueError, match="MiB as PNG"):
        browser.BrowserEditor(shape, {"tps": op}, image=image, image_frame=to_pixels)


def test_widget_sends_the_picture_once(operators, shape):
    image, to_pixels = picture_for(shape.mesh)
    editor = browser.BrowserEditor(shape, dict(operators), basis="tps", image=image, image_frame=to_pixels)
    meta, data = editor.image_meta, editor.image_data
    assert meta["scalars"]["image_size"] == [image.shape[1], image.shape[0]]
    a = meta["arrays"]
    png = np.frombuffer(data, np.uint8, a["image_png"]["length"], a["image_png"]["offset"])
    np.testing.assert_array_equal(_png_array(png), np.round(image * 255).astype(np.uint8))
    uv = np.frombuffer(data, np.float32, a["uv"]["length"], a["uv"]["offset"]).reshape(-1, 2)
    V_px = to_pixels(shape.mesh.V)
    np.testing.assert_allclose(uv * [image.shape[1], image.shape[0]] - 0.5, V_px, atol=1e-4)  # rest pose → picture
    assert "image_png" not in editor.payload_meta["arrays"]  # not in the operator's payload (resent on a basis switch)
    sent = []
    editor.observe(lambda c: sent.append(c["name"]), names=["image_data", "payload_data"])
    editor.basis = "linear"
    assert sent == ["payload_data"] and editor.image_data is data


def _textured_colours(page, editor, points):
    """The canvas colours at mesh points (k,2) of the current pose, in [0,1] (a screenshot of the canvas)."""
    from test_browser import _png_to_array

    screen = np.array(
        page.evaluate(f"(pts) => pts.map(([x, y]) => {editor}.st.view.toScreen(x, y))", np.asarray(points).tolist())
    )
    shot = _png_to_array(page.locator("canvas.defop-canvas").first.screenshot()) / 255.0
    ij = np.floor(screen).astype(int)
    return shot[ij[:, 1], ij[:, 0]], shot


def _picture_colours(image, px):
    """The picture sampled bilinearly at pixel positions (k,2) (x = column, y = row), as the texture is."""
    from scipy.ndimage import map_coordinates

    return np.stack(
        [map_coordinates(image[..., c], [px[:, 1], px[:, 0]], order=1, mode="nearest") for c in range(image.shape[2])],
        axis=-1,
    )


_WIDGET_HOST = """<!DOCTYPE html><html><head><meta charset="utf-8"></head><body><div id="host"></div>
<script type="module">
{js}
window.defopRender = render; window.defopDecode = fromBase64;
</script></body></html>"""

# anywidget's contract with the module: render({model, el}) with model.get/set/on/save_changes
_MOUNT_WIDGET = """(traits) => {
  const values = {};
  for (const [k, v] of Object.entries(traits)) {
    values[k] = v && v.base64 !== undefined ? new DataView(window.defopDecode(v.base64).buffer) : v;
  }
  const model = { get: (k) => values[k], set: (k, v) => { values[k] = v; }, on: () => {}, save_changes: () => {} };
  const el = document.getElementById("host");
  window.defopRender({ model, el });
  window.defopEditor = el.defopEditor;
}"""


def _open_picture_editor(page, how, op, shape, image, to_pixels, tmp_path):
    """The picture editor in the page: the standalone HTML of to_html, or the anywidget's module with its traits."""
    if how == "standalone":
        path = export.to_html(op, tmp_path / "picture.html", shape=shape, image=image, image_frame=to_pixels)
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        return
    widget = browser.BrowserEditor(shape, {"tps": op}, kinds=("tps",), image=image, image_frame=to_pixels)
    traits = {k: getattr(widget, k) for k in ("payload_meta", "q", "gt_meta", "image_meta")}
    for k in ("payload_data", "gt_data", "image_data"):
        traits[k] = {"base64": base64.b64encode(getattr(widget, k)).decode()}
    host = tmp_path / "host.html"
    host.write_text(_WIDGET_HOST.format(js=payload.JS_PATH.read_text()))
    page.goto(host.as_uri())
    page.wait_for_function("() => window.defopRender")
    page.evaluate(_MOUNT_WIDGET, traits)


def _drag_picture(page, editor, shape, image, to_pixels):
    """Drag handle 0 of a picture editor with the mouse; assert the handle followed, the picture is textured on
    the mesh (colours at triangle centroids match the picture at the rest centroids), and after the drag the
    deformed triangles still carry their rest colours (the picture moved with the mesh)."""
    F = shape.mesh.F
    assert page.evaluate(f"() => {editor}.imageReady") is True
    text = page.evaluate(f"() => {editor}.ui.readout.textContent")
    assert f"picture {image.shape[1]} × {image.shape[0]} px: textured (WebGL)" in text, text
    X0 = np.array(page.evaluate(f"() => Array.from({editor}.st.X)")).reshape(-1, 2)
    rest, before = _textured_colours(page, editor, X0[F].mean(axis=1))
    end = mouse_drag(page, editor, 45, -35)
    page.wait_for_timeout(100)
    Q = np.array(page.evaluate(f"() => Array.from({editor}.st.Q)")).reshape(-1, 2)
    X1 = np.array(page.evaluate(f"() => Array.from({editor}.st.X)")).reshape(-1, 2)
    moved, after = _textured_colours(page, editor, X1[F].mean(axis=1))
    # the handle followed the mouse, the mesh followed the handle
    np.testing.assert_allclose(Q[0], end, atol=1e-9)
    np.testing.assert_allclose(X1[shape.moving_handles[0]], end, atol=1e-6 * shape.mesh.bbox_diagonal)
    assert np.linalg.norm(end - shape.P_moving[0]) > 0.05 * shape.mesh.bbox_diagonal
    # texture, not the plain fill (0.949, 0.843, 0.651): the picture's colour at each rest centroid
    expected = _picture_colours(image, to_pixels(X0[F].mean(axis=1)))
    err_rest = np.abs(rest - expected).max(axis=1)
    fill = np.array([0.949, 0.843, 0.651])
    assert np.mean(np.abs(rest - fill).max(axis=1) > 0.1) > 0.8, "the mesh is drawn with its plain fill"
    assert np.quantile(err_rest, 0.9) < 0.06, f"rest colours differ from the picture: {np.quantile(err_rest, 0.9)}"
    # after the drag every unflipped triangle carries its rest colours ...
    keep = ~np.asarray(shape.mesh.flipped(X1))
    err_moved = np.abs(moved - expected)[keep].max(axis=1)
    assert np.quantile(err_moved, 0.9) < 0.06, f"the picture did not follow the mesh: {np.quantile(err_moved, 0.9)}"
    # ... and the canvas changed where the mesh moved
    changed = np.mean(np.any(np.abs(after - before) > 30 / 255, axis=2))
    assert changed > 0.005, f"only {changed:.2%} of the canvas pixels changed"
    return Q


@pytest.mark.browser
@pytest.mark.parametrize("how", ["standalone", "widget"])
def test_picture_editor_drag_in_chromium(operators, shape, tmp_path, how):
    """The standalone page of to_html(image=...), and the widget's module mounted as anywidget does."""
    op = operators["tps"]
    image, to_pixels = picture_for(shape.mesh)
    with chromium_page() as page:
        _open_picture_editor(page, how, op, shape, image, to_pixels, tmp_path)
        _drag_picture(page, "window.defopEditor", shape, image, to_pixels)
        page.screenshot(path=f"/tmp/defop_picture_drag_{how}.png")
        errors, requests = page.errors, page.requests
    assert not errors, errors
    assert all(url.startswith(("file:", "data:", "about:", "blob:")) for url in requests), requests


_PICTURE_NOTEBOOK = [
    "import json, sys\nimport defop as dop\nfrom defop.editor.browser import BrowserEditor\n"
    f"sys.path.insert(0, {str(ROOT / 'tests')!r})\nfrom test_browser_editor import picture_for",
    f"shape = dop.shapes.load({SHAPE!r})\npicture, to_pixels = picture_for(shape.mesh)\n"
    "editor = BrowserEditor(shape, basis='tps', kinds=('tps',), m=20, image=picture, image_frame=to_pixels)\n"
    "editor.observe(lambda c: open('q.json', 'w').write(json.dumps(c['new'])), names='q')\neditor",
]


@pytest.mark.browser
@pytest.mark.parametrize("widget_lab", [_PICTURE_NOTEBOOK], indirect=True, ids=["picture"])
def test_picture_widget_drag_in_jupyterlab(widget_lab):
    """The picture editor as a widget in JupyterLab: textured, dragged with the mouse, Q back in the kernel."""
    from test_browser import _KERNEL_IDLE

    shape = dop.shapes.load(SHAPE)
    image, to_pixels = picture_for(shape.mesh)
    editor = "document.querySelector('.defop-editor').parentNode.defopEditor"
    with chromium_page(viewport=(1400, 1000)) as page:
        open_lab_notebook(page, widget_lab)
        page.wait_for_function(f"() => {editor}.imageReady !== undefined")
        Q = _drag_picture(page, editor, shape, image, to_pixels)
        page.screenshot(path="/tmp/defop_picture_jupyterlab.png")
        page.wait_for_function(_KERNEL_IDLE, timeout=30_000)
        q_file = widget_lab["root"] / "q.json"
        for _ in range(100):
            if q_file.exists():
                break
            page.wait_for_timeout(100)
    np.testing.assert_allclose(np.reshape(json.loads(q_file.read_text()), (-1, 2)), Q, atol=1e-12)


@pytest.mark.browser
def test_picture_without_webgl_says_so(operators, shape, tmp_path):
    """Without WebGL the 2D fallback draws the plain mesh, the readout says the picture is not drawn, and dragging
    still works."""
    op = operators["tps"]
    image, to_pixels = picture_for(shape.mesh)
    path = export.to_html(op, tmp_path / "picture.html", shape=shape, image=image, image_frame=to_pixels)
    with chromium_page(["--disable-3d-apis"]) as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        assert page.evaluate("() => window.defopEditor.imageReady") is False
        text = page.evaluate("() => window.defopEditor.ui.readout.textContent")
        end = mouse_drag(page, "window.defopEditor", 40, -30)
        Q = np.array(page.evaluate("() => Array.from(window.defopEditor.st.Q)")).reshape(-1, 2)
        errors = page.errors
    assert not errors, errors
    assert f"picture {image.shape[1]} × {image.shape[0]} px: not drawn (needs WebGL)" in text, text
    np.testing.assert_allclose(Q[0], end, atol=1e-9)
