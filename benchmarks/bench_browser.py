"""In-page editor benchmark (issue #18): frame rate of a scripted drag on the octopus in headless Chromium.

The octopus (about 3.9k vertices, 9 moving handles) with an S-ARAP TPS operator trained on a modest
m = 40 samples (the basis needs at least 2n + 2 = 20; ``python benchmarks/bench_browser.py [m]``), written
as a standalone page by :func:`defop.browser.to_html`. In the page, a 200-step drag of one handle is
scripted from ``requestAnimationFrame``: every animation frame dispatches one ``pointermove`` to the
canvas, so the editor has one new Q per frame; the frame timestamps are the rAF timestamps. Prints the
median and 5th-percentile frame rate and the editor's own median per-frame evaluation and drawing times.

Side by side, in the same run, today's ipympl editor :class:`defop.widgets.HandleEditor` is dragged in
JupyterLab with the same operator and the same in-page scripted drag (mouse events, which ipympl listens
to); its frames are the images ipympl draws into its canvas (``drawImage`` wrapped), counted until the
kernel has caught up.

Target: >= 55 fps median in the page. Headless Chromium runs with ``--disable-gpu`` (WebGL through
SwiftShader) on a shared 2-core machine: timings are noisy, compare the two rows of one run. Needs
Debian's chromium, playwright and jupyterlab; ``--no-ipympl`` skips the JupyterLab part.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import defop as dop
from defop import browser

CHROMIUM = os.environ.get("DEFOP_CHROMIUM") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-dev-shm-usage"]

DRAG = """async ([x0, y0, dx, dy, steps]) => {
  // one pointer step per animation frame, out and back; pointer and mouse events (ipympl listens to mouse ones)
  const target = document.elementFromPoint(x0, y0);
  const fire = (kind, x, y) => {
    const o = {clientX: x, clientY: y, pointerId: 1, isPrimary: true, bubbles: true, button: 0, buttons: 1};
    target.dispatchEvent(new PointerEvent("pointer" + kind, o));
    target.dispatchEvent(new MouseEvent("mouse" + kind, o));
  };
  fire("down", x0, y0);
  await new Promise((done) => {
    let k = 0;
    const step = () => {
      if (k === steps) { done(); return; }
      k += 1;
      const s = Math.sin((Math.PI * k) / steps);
      fire("move", x0 + s * dx, y0 + s * dy);
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  });
  fire("up", x0, y0);
}"""


def rates(stamps):
    """Median and 5th-percentile frame rate from frame timestamps (ms); draws < 2 ms apart are one frame."""
    t = np.asarray(stamps, float)
    t = t[np.concatenate([[True], np.diff(t) > 2.0])] if len(t) else t
    if len(t) < 3:
        return float("nan"), float("nan"), len(t), 0.0
    fps = 1000.0 / np.diff(t)
    return float(np.median(fps)), float(np.percentile(fps, 5)), len(t), (t[-1] - t[0]) / 1000


def in_page(page_path, steps):
    """The standalone page: frame timestamps of the editor's rAF frames, and its own per-frame timings."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        page = chromium.new_page(viewport={"width": 1280, "height": 720})
        page.goto(page_path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        box = page.locator("canvas.defop-canvas").bounding_box()
        u, v = page.evaluate("() => window.defopEditor.handleScreen(0)")
        start = [box["x"] + u, box["y"] + v]
        page.evaluate(DRAG, [*start, 30, -20, 20])  # warm-up: JIT
        page.evaluate("() => { const e = window.defopEditor; window.__stamps = []; e.st.evalMs = [];"
                      " e.st.drawMs = []; e.onFrame = (t) => window.__stamps.push(t); }")
        page.evaluate(DRAG, [*start, 160, -120, steps])
        res = page.evaluate("() => ({stamps: window.__stamps, evalMs: window.defopEditor.st.evalMs,"
                            " drawMs: window.defopEditor.st.drawMs})")
        page.screenshot(path="/tmp/defop_bench_octopus.png")
        chromium.close()
    return res


def main(m=40, steps=200, ipympl=True):
    shape = dop.shapes.load("octopus")
    t0 = time.perf_counter()
    op, _ = dop.train.train(shape, basis="tps", m=m, progress=False)
    print(f"octopus: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles; {op} "
          f"({time.perf_counter() - t0:.0f} s to train or load from the cache)")
    with tempfile.TemporaryDirectory() as tmp:
        page_path = browser.to_html(op, Path(tmp) / "octopus.html", shape=shape)
        print(f"standalone page: {page_path.stat().st_size / 1e6:.1f} MB")
        res = in_page(page_path, steps)
    print(f"{steps}-step drag of one handle, one pointer event per animation frame, frames shown per second:")
    row = "  {:<34} median {:5.1f} fps, 5th percentile {:5.1f} fps ({} frames in {:.1f} s)"
    med, p5, n, span = rates(res["stamps"])
    print(row.format("in-page editor (this module):", med, p5, n, span))
    print(f"    per frame in the page: evaluation {np.median(res['evalMs']):.2f} ms, "
          f"draw submission {np.median(res['drawMs']):.2f} ms (medians)")
    if ipympl:
        from bench_browser_ipympl import ipympl_drag

        print(row.format("ipympl editor (kernel round trip):", *rates(ipympl_drag(m, steps, DRAG))))
    print(f"target >= 55 fps median in the page: {'met' if med >= 55 else 'NOT met'}")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(*(int(a) for a in args[:1]), ipympl="--no-ipympl" not in sys.argv)
