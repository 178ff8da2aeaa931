"""Today's ipympl editor dragged in JupyterLab, for the side-by-side of ``bench_browser.py`` (not run alone).

A throw-away JupyterLab (the set-up of ``tests/test_browser.py``) runs a notebook that loads the same
cached octopus operator into :class:`defop.editor.widgets.HandleEditor`; every image ipympl draws into its canvas
is timestamped (``drawImage`` wrapped) while the pointer drags the first moving handle.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_browser import (  # noqa: E402
    _CELL_ERRORS,
    _KERNEL_IDLE,
    _NOTEBOOK_DONE,
    CHROMIUM,
    CHROMIUM_ARGS,
    TOKEN,
    _free_port,
    _wait_for_server,
)

CELL = """%matplotlib widget
import defop as dop
shape = dop.shapes.load("octopus")
op, _ = dop.train(shape, basis="tps", m={m}, progress=False)
editor = dop.editor.widgets.HandleEditor(shape, operators={{"tps": op}}, basis="tps")
editor"""

WRAP_DRAW = """() => { window.__draws = []; const proto = CanvasRenderingContext2D.prototype, orig = proto.drawImage;
  proto.drawImage = function (...a) { window.__draws.push(performance.now()); return orig.apply(this, a); }; }"""


def _notebook(path, m):
    import nbformat

    nb = nbformat.v4.new_notebook(
        cells=[nbformat.v4.new_code_cell(CELL.format(m=m))],
        metadata={"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
    )
    nbformat.write(nb, path)


def _wait_caught_up(page, quiet_s=3, timeout_s=180):
    """Until the kernel has been idle and no image was drawn for ``quiet_s`` seconds (the queued moves are done)."""
    quiet, last = 0, -1
    for _ in range(timeout_s):
        page.wait_for_timeout(1000)
        n = page.evaluate("() => window.__draws.length")
        quiet = quiet + 1 if (n == last and page.evaluate(_KERNEL_IDLE)) else 0
        last = n
        if quiet >= quiet_s:
            return
    raise RuntimeError(f"the ipympl editor did not catch up within {timeout_s} s")


def ipympl_drag(m, steps, drag_js):
    """Drag the ipympl editor's first handle; returns the timestamps (ms) of the images drawn during the drag."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        root = tmp / "nb"
        root.mkdir()
        _notebook(root / "ipympl.ipynb", m)
        env = dict(
            os.environ,
            JUPYTER_CONFIG_DIR=str(tmp / "jc"),
            JUPYTER_RUNTIME_DIR=str(tmp / "jr"),
            JUPYTERLAB_WORKSPACES_DIR=str(tmp / "lw"),
            IPYTHONDIR=str(tmp / "ip"),
            MPLCONFIGDIR=str(tmp / "mpl"),
        )
        env.pop("MPLBACKEND", None)
        port = _free_port()
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
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        try:
            url = f"http://127.0.0.1:{port}"
            _wait_for_server(url, proc)
            with sync_playwright() as p:
                chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
                page = chromium.new_page(viewport={"width": 1400, "height": 1000})
                page.set_default_timeout(60_000)
                page.goto(f"{url}/lab/tree/ipympl.ipynb?token={TOKEN}")
                page.wait_for_function(_KERNEL_IDLE, timeout=90_000)
                page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
                page.wait_for_function(_NOTEBOOK_DONE, timeout=300_000, polling=500)
                errors = page.evaluate(_CELL_ERRORS)
                if errors:
                    raise RuntimeError("the ipympl notebook failed: " + "; ".join(errors))
                canvas = page.locator(".jupyter-matplotlib-canvas-div").first
                canvas.scroll_into_view_if_needed()
                page.wait_for_timeout(1500)
                box = canvas.bounding_box()
                data = page.locator(".defop-handles .defop-handle-data").first
                uv = json.loads(data.get_attribute("data-uv"))[0]
                page.evaluate(WRAP_DRAW)
                start = [box["x"] + uv[0] * box["width"], box["y"] + uv[1] * box["height"]]
                page.evaluate(drag_js, [*start, 160, -120, steps])
                _wait_caught_up(page)
                draws = page.evaluate("() => window.__draws")
                page.screenshot(path="/tmp/defop_bench_ipympl.png")
                chromium.close()
        finally:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
    return draws
