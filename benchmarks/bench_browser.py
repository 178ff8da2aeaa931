"""In-page editor benchmark (issue #18): frame rate of a scripted drag on the octopus in headless Chromium.

The octopus (about 3.9k vertices, 9 moving handles) with an S-ARAP TPS operator trained on a modest
m = 40 samples (the basis needs at least 2n + 2 = 20; ``python benchmarks/bench_browser.py [m]``), written
as a standalone page by :func:`defop.browser.to_html`. In the page, a 200-step drag of one handle is
scripted from ``requestAnimationFrame``: every animation frame dispatches one ``pointermove`` to the
canvas, so the editor has one new Q per frame; the frame timestamps are the rAF timestamps. Prints the
median and 5th-percentile frame rate and the editor's own median per-frame evaluation and drawing times.

Target: >= 55 fps median in the page. Headless Chromium runs with ``--disable-gpu`` (software
rasterisation) on a shared 2-core machine: timings are noisy. Needs Debian's chromium and playwright.
Today's ipympl editor (kernel round trip per frame) is NOT measured here (see the report of issue #18).
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

DRAG = """async ([steps, dx, dy]) => {
  const e = window.defopEditor, canvas = e.ui.canvas, r = canvas.getBoundingClientRect();
  const [u0, v0] = e.handleScreen(0), x0 = r.left + u0, y0 = r.top + v0;
  const ev = (type, x, y) => canvas.dispatchEvent(new PointerEvent(type,
      {clientX: x, clientY: y, pointerId: 1, isPrimary: true, bubbles: true, buttons: 1}));
  ev("pointerdown", x0, y0);
  e.st.evalMs = []; e.st.drawMs = [];
  const stamps = [];
  await new Promise((done) => {
    let k = 0;
    const step = (t) => {
      stamps.push(t);
      if (k === steps) { done(); return; }
      k += 1;
      const s = Math.sin((Math.PI * k) / steps);  // out and back
      ev("pointermove", x0 + s * dx, y0 + s * dy);
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  });
  ev("pointerup", x0, y0);
  return {stamps, evalMs: e.st.evalMs, drawMs: e.st.drawMs, n: e.st.p.n_vertices};
}"""


def main(m=40, steps=200):
    from playwright.sync_api import sync_playwright

    shape = dop.shapes.load("octopus")
    t0 = time.perf_counter()
    op, _ = dop.train.train(shape, basis="tps", m=m, progress=False)
    print(f"octopus: {shape.mesh.n_vertices} vertices, {shape.n_moving} moving handles; {op} "
          f"({time.perf_counter() - t0:.0f} s to train or load from the cache)")
    with tempfile.TemporaryDirectory() as tmp:
        page_path = browser.to_html(op, Path(tmp) / "octopus.html", shape=shape)
        print(f"standalone page: {page_path.stat().st_size / 1e6:.1f} MB")
        with sync_playwright() as p:
            chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
            page = chromium.new_page(viewport={"width": 1280, "height": 720})
            page.goto(page_path.as_uri())
            page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
            page.evaluate(DRAG, [20, 30, -20])  # warm-up: JIT
            res = page.evaluate(DRAG, [steps, 160, -120])
            page.screenshot(path="/tmp/defop_bench_octopus.png")
            chromium.close()
    dt = np.diff(res["stamps"])
    fps = 1000.0 / dt
    print(f"in-page editor, {steps}-step drag, {res['n']} vertices:")
    print(f"  frame rate: median {np.median(fps):.1f} fps, 5th percentile {np.percentile(fps, 5):.1f} fps")
    print(f"  per frame: evaluation median {np.median(res['evalMs']):.2f} ms, "
          f"drawing median {np.median(res['drawMs']):.2f} ms ({len(res['evalMs'])} frames)")
    print(f"  target >= 55 fps median: {'met' if np.median(fps) >= 55 else 'NOT met'}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
