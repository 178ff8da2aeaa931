"""End-to-end: drag a handle of the playground notebook in a real browser.

A JupyterLab server is started on localhost (random free port, known token, throw-away
config/runtime/settings directories), headless Chromium is driven with Playwright, the
playground notebook (a temporary copy) is run with "Run All Cells", and a handle of the in-page
editor (:class:`defop.editor.browser.BrowserEditor`) is dragged with the mouse. The test asserts that the
editor fits in one screen, the handle followed the pointer, the mesh moved (the page's X and the
canvas pixels) and Q came back to Python (``editor.Q`` read through the kernel). With
``DEFOP_SCREENSHOT=path`` the page after the drag is saved there.

Needs Debian's ``chromium`` (``apt-get install -y --no-install-recommends chromium``) and the
Python ``playwright`` package (``pip install playwright``; no ``playwright install``: the system
Chromium is used through ``executable_path``). Skips with the reason when either is missing.
Run with ``pytest -m browser tests/test_browser.py``.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.browser

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK = REPO / "notebooks" / "11_playground.ipynb"
CHROMIUM = os.environ.get("DEFOP_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--disable-quic",
    "--disable-dev-shm-usage",
]
TOKEN = "defop-browser-test"
RUN_TIMEOUT_MS = 240_000  # run-all, including fast-mode training with an empty cache


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_server(url, proc, timeout=90.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"JupyterLab exited early with code {proc.returncode}")
        try:
            with urllib.request.urlopen(f"{url}/api/status?token={TOKEN}", timeout=2) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, OSError):
            pass
        time.sleep(0.5)
    raise RuntimeError(f"JupyterLab did not answer at {url} within {timeout:.0f} s")


@pytest.fixture
def lab(tmp_path):
    """A JupyterLab server serving a temporary copy of the playground notebook."""
    if not NOTEBOOK.exists():
        pytest.skip(f"{NOTEBOOK} does not exist")
    root = tmp_path / "notebooks"
    root.mkdir()
    shutil.copy(NOTEBOOK, root / NOTEBOOK.name)
    settings = tmp_path / "lab-settings"
    news = settings / "@jupyterlab" / "apputils-extension"
    news.mkdir(parents=True)
    # no news / update checks: nothing leaves localhost
    (news / "notification.jupyterlab-settings").write_text(json.dumps({"fetchNews": "false", "checkForUpdates": False}))
    env = dict(os.environ)
    env.update(
        DEFOP_FAST="1",
        DEFOP_CACHE=str(tmp_path / "cache"),
        DEFOP_N_JOBS=env.get("DEFOP_N_JOBS", "2"),
        JUPYTER_CONFIG_DIR=str(tmp_path / "jupyter-config"),
        JUPYTER_RUNTIME_DIR=str(tmp_path / "jupyter-runtime"),
        JUPYTERLAB_SETTINGS_DIR=str(settings),
        JUPYTERLAB_WORKSPACES_DIR=str(tmp_path / "lab-workspaces"),
        IPYTHONDIR=str(tmp_path / "ipython"),
        MPLCONFIGDIR=str(tmp_path / "mpl"),
        PYTHONPATH=os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p),
    )
    env.pop("MPLBACKEND", None)
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    cmd = [
        sys.executable,
        "-m",
        "jupyterlab",
        "--ServerApp.ip=127.0.0.1",
        f"--ServerApp.port={port}",
        "--ServerApp.port_retries=0",
        f"--IdentityProvider.token={TOKEN}",
        "--ServerApp.open_browser=False",
        "--no-browser",
        "--allow-root",
        f"--ServerApp.root_dir={root}",
        "--LabApp.expose_app_in_browser=True",
    ]
    log = open(tmp_path / "jupyterlab.log", "w")  # noqa: SIM115 - closed below
    proc = subprocess.Popen(
        cmd,
        env=env,
        cwd=root,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        _wait_for_server(url, proc)
        yield {
            "url": url,
            "notebook": NOTEBOOK.name,
            "log": tmp_path / "jupyterlab.log",
            "tmp": tmp_path,
        }
    finally:
        stop_server(proc, log)


def _png_to_array(data):
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.int16)


_NOTEBOOK_DONE = """() => {
    const app = window.jupyterapp;
    const panel = app && app.shell.currentWidget;
    if (!panel || !panel.content || !panel.sessionContext) return false;
    const kernel = panel.sessionContext.session && panel.sessionContext.session.kernel;
    if (!kernel || kernel.status !== 'idle') return false;
    const code = panel.content.widgets.filter(c => c.model.type === 'code');
    if (code.some(c => c.model.outputs.toJSON().some(o => o.output_type === 'error'))) return true;  // run-all stopped
    return code.every(c => c.model.executionCount);
}"""

_KERNEL_IDLE = """() => {
    const app = window.jupyterapp;
    const panel = app && app.shell.currentWidget;
    const kernel = panel && panel.sessionContext && panel.sessionContext.session && panel.sessionContext.session.kernel;
    return !!kernel && kernel.status === 'idle';
}"""

_CELL_ERRORS = """() => window.jupyterapp.shell.currentWidget.content.widgets
    .filter(c => c.model.type === 'code')
    .flatMap(c => c.model.outputs.toJSON().filter(o => o.output_type === 'error'))
    .map(o => o.ename + ': ' + o.evalue)"""


_EDITOR = "document.querySelector('.defop-editor').parentNode.defopEditor"

_KERNEL_Q = """async () => {
    const kernel = window.jupyterapp.shell.currentWidget.sessionContext.session.kernel;
    const future = kernel.requestExecute({code: 'import json; print(json.dumps(editor.Q.tolist()))'});
    let out = '';
    future.onIOPub = (msg) => { if (msg.header.msg_type === 'stream') out += msg.content.text; };
    await future.done;
    return out;
}"""


def _page_state(page):
    X = np.array(page.evaluate(f"() => Array.from({_EDITOR}.st.X)")).reshape(-1, 2)
    Q = np.array(page.evaluate(f"() => Array.from({_EDITOR}.st.Q)")).reshape(-1, 2)
    return X, Q


def test_drag_handle_in_jupyterlab(lab):
    sync_api = pytest.importorskip("playwright.sync_api", reason="the Python package playwright is not installed")
    if not (os.path.isfile(CHROMIUM) and os.access(CHROMIUM, os.X_OK)):
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install -y --no-install-recommends chromium)")

    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        console = []
        page.on("console", lambda msg: console.append(f"{msg.type}: {msg.text}"))
        try:
            _drive(page, lab)
        except Exception:
            page.screenshot(path=str(lab["tmp"] / "failure.png"), full_page=True)
            print("browser console:\n" + "\n".join(console[-40:]))
            print("server log:\n" + lab["log"].read_text()[-4000:])
            print("failure screenshot:", lab["tmp"] / "failure.png")
            raise
        finally:
            browser.close()


def stop_server(proc, log):
    """Stop a server started with ``start_new_session=True`` (SIGTERM to its group: the kernels it started too,
    SIGKILL after 20 s) and close its log."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    log.close()


def run_all_cells(page, url, timeout_ms):
    """Open the notebook at ``url`` in JupyterLab, run every cell (the Run menu's "Run All Cells" command) and
    return the errors of failed cells (a list of str, empty when all ran)."""
    page.set_default_timeout(60_000)
    page.goto(url)
    page.wait_for_selector(".jp-Notebook .jp-Cell")
    page.wait_for_function(_KERNEL_IDLE, timeout=90_000)
    page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
    page.wait_for_function(_NOTEBOOK_DONE, timeout=timeout_ms, polling=500)
    return page.evaluate(_CELL_ERRORS)


def _drive(page, lab):
    # 1-2. open the notebook and run every cell
    errors = run_all_cells(page, f"{lab['url']}/lab/tree/{lab['notebook']}?token={TOKEN}", RUN_TIMEOUT_MS)
    assert not errors, "a cell failed: " + "; ".join(errors)

    # the in-page editor (an anywidget): canvas, controls and readout fit in one screen
    canvas = page.locator(".defop-editor canvas.defop-canvas").first
    canvas.wait_for(state="visible")
    page.locator(".defop-editor").first.scroll_into_view_if_needed()
    page.wait_for_timeout(500)
    viewport = page.viewport_size
    for part in (".defop-editor canvas.defop-canvas", ".defop-editor .defop-controls", ".defop-editor .defop-readout"):
        b = page.locator(part).first.bounding_box()
        assert b["y"] >= 0 and b["y"] + b["height"] <= viewport["height"], (part, b, viewport)
        assert b["x"] >= 0 and b["x"] + b["width"] <= viewport["width"], (part, b, viewport)
    page.screenshot(path=str(lab["tmp"] / "playground.png"))
    X0, Q0 = _page_state(page)
    box = canvas.bounding_box()
    before = _png_to_array(canvas.screenshot())

    # 3. drag the first moving handle right and up with the mouse
    u, v = page.evaluate(f"() => {_EDITOR}.handleScreen(0)")
    x0, y0 = box["x"] + u, box["y"] + v
    dx, dy = 50, -40
    page.mouse.move(x0, y0)
    page.mouse.down()
    for t in np.linspace(0.1, 1.0, 12):
        page.mouse.move(x0 + t * dx, y0 + t * dy)
        page.wait_for_timeout(30)
    page.mouse.up()
    end = np.array(page.evaluate(f"([u, v]) => {_EDITOR}.st.view.toData(u, v)", [u + dx, v + dy]))
    X1, Q1 = _page_state(page)
    page.wait_for_function(_KERNEL_IDLE, timeout=30_000)
    page.wait_for_timeout(300)
    after = _png_to_array(canvas.screenshot(path=str(lab["tmp"] / "canvas-after.png")))

    # 4. the handle followed the pointer, the mesh moved in the page, and Q came back to Python
    np.testing.assert_allclose(Q1[0], end, atol=1e-9)
    assert Q1[0, 0] > Q0[0, 0] and Q1[0, 1] > Q0[0, 1], (Q0, Q1)  # screen right/up = data +x/+y
    np.testing.assert_allclose(Q1[1:], Q0[1:])  # the other handles stayed
    diag = np.linalg.norm(np.ptp(X0, axis=0))
    assert np.max(np.linalg.norm(X1 - X0, axis=1)) > 0.01 * diag
    changed = np.mean(np.any(np.abs(after - before) > 30, axis=2))
    assert changed > 0.005, f"only {changed:.2%} of the canvas pixels changed"
    Q_py = np.array(json.loads(page.evaluate(_KERNEL_Q)))
    np.testing.assert_allclose(Q_py, Q1, atol=1e-12)
    page.screenshot(path=str(lab["tmp"] / "playground-after.png"))
    if os.environ.get("DEFOP_SCREENSHOT"):
        shutil.copy(lab["tmp"] / "playground-after.png", os.environ["DEFOP_SCREENSHOT"])
