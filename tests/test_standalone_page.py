"""The standalone page of :func:`defop.editor.export.to_html` reads as a page: its title and one instruction above
the canvas, a legend of the marks, the numbers folded behind a "details" toggle, and a frame rate counted from the
frames the browser rendered (every requestAnimationFrame while a handle is held), not from pointer events."""

from __future__ import annotations

import pytest
from test_browser_editor import chromium_page, operators, shape  # noqa: F401  (fixtures)

from defop.editor import export


@pytest.mark.browser
def test_standalone_page_layout_legend_details_and_frame_rate(operators, shape, tmp_path):  # noqa: F811
    path = export.to_html(operators["tps"], tmp_path / "page.html", shape=shape, title="U shape <TPS>")
    with chromium_page() as page:
        page.goto(path.as_uri())
        page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X")
        canvas = page.locator("canvas.defop-canvas").bounding_box()
        h1 = page.locator("h1").bounding_box()
        instruction = page.locator(".defop-instruction")
        heading = page.locator("h1").text_content()
        said = instruction.text_content()
        below = instruction.bounding_box()
        legend = " ".join(page.locator(".defop-legend").text_content().split())
        details = page.evaluate(
            "() => { const d = document.querySelector('details.defop-details');"
            " return {open: d.open, holds: d.contains(window.defopEditor.ui.readout)}; }"
        )
        readout_shown = page.locator(".defop-readout").first.is_visible()
        # hold a handle still: frames are rendered (and counted) while no pointer event arrives
        u, v = page.evaluate("() => window.defopEditor.handleScreen(0)")
        page.mouse.move(canvas["x"] + u, canvas["y"] + v)
        page.mouse.down()
        page.wait_for_function("() => window.defopEditor.st.frames.length >= 5", timeout=30_000)
        held = page.evaluate(
            "() => ({frames: window.defopEditor.st.frames.length, updates: window.defopEditor.st.updates.length})"
        )
        page.mouse.move(canvas["x"] + u + 30, canvas["y"] + v - 20, steps=5)
        page.wait_for_function("() => window.defopEditor.st.updates.length >= 1", timeout=30_000)
        page.mouse.up()
        text = page.evaluate("() => window.defopEditor.ui.readout.textContent")
        errors = page.errors
    assert not errors, errors
    assert heading == "U shape <TPS>"
    assert h1["y"] + h1["height"] <= below["y"] and below["y"] + below["height"] <= canvas["y"], "title, line, canvas"
    assert said.startswith("Drag a red handle") and said.count(".") == 1, said
    for mark in ("moving handle", "fixed handle", "sampling region", "Voronoi cell", "extrapolates", "flipped"):
        assert mark in legend, mark
    assert details == {"open": False, "holds": True} and not readout_shown, "the readout is folded away"
    assert held["frames"] >= 5 and held["updates"] == 0, held  # frames counted without any pointer move
    assert "fps (frames the browser rendered while dragging)" in text, text
