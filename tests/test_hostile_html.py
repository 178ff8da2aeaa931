"""Hostile titles and shape names for the standalone page (issue 26): shown as text, nothing runs, atomic writes.

The page inlines its script and the operator's metadata (JSON) in one ``<script>``. A title holding ``<!--``
and ``<script>`` put the HTML parser into the script's "double escaped" state, where the real ``</script>`` no
longer ends it: the page opened blank. The checks here parse the written page with the standard library's HTML
parser (independent of the writer), decode the metadata back, and open the pages in headless Chromium.
"""

from __future__ import annotations

import html.parser
import json
import os
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hostile_editor import setup  # noqa: F401 - the shared fixture

from defop.editor import export

HOSTILE = [
    "<!--",
    "</script>",
    "<script>window.pwned=1</script>",
    "<!--<script>",
    "a<!--<script>x</script>-->b",
    "</SCRIPT ><img src=x onerror=window.pwned=1>",
    "</title><script>window.pwned=1</script>",
    "&lt;&amp;\"'`${window.pwned=1}",
    "\u2028\u2029 line separators",
    "🙂 Ψ ∑ \u0000 nul",
    "]]><![CDATA[",
]


@pytest.fixture(scope="module")
def op(setup):  # noqa: F811 - the fixture imported above
    """The bar's TPS DefOp, trained once (the fixture of test_hostile_editor)."""
    return setup[1]["tps"]


class _Page(html.parser.HTMLParser):
    """The elements the page is made of, as a browser's tokenizer sees them."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags, self.title, self.scripts, self._in = [], "", [], None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self._in = tag

    def handle_endtag(self, tag):
        self._in = None

    def handle_data(self, data):
        if self._in == "title":
            self.title += data
        elif self._in == "script":
            self.scripts.append(data)


def _parse(path):
    text = path.read_bytes().decode("utf-8")  # strict: the page is valid UTF-8
    page = _Page()
    page.feed(text)
    return text, page


def _embedded_meta(script):
    """The metadata object passed to mountStandalone, decoded as JSON (\\u003c is a valid JSON escape)."""
    start = script.rindex("window.defopEditor = mountStandalone(")
    body = script[start:]
    first = body.index("{")
    meta, _end = json.JSONDecoder().raw_decode(body[first:])
    return meta


def _check_page(path, title):
    text, page = _parse(path)
    assert page.tags.count("script") == 1 and page.tags.count("img") == 0, page.tags
    assert page.title == title
    (script,) = page.scripts
    lowered = script.lower()
    assert "</script" not in lowered and "<!--" not in lowered and "<script" not in lowered
    assert _embedded_meta(script)["scalars"]["title"] == title
    return text


@pytest.mark.parametrize("title", HOSTILE)
def test_a_hostile_title_is_text_in_the_title_and_in_the_script(op, tmp_path, title):
    _check_page(export.to_html(op, tmp_path / "page.html", title=title), title)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(title=st.text(alphabet=st.sampled_from(list("<>!-/&;'\"`\\ sScriptT\u2028é🙂")) | st.characters(), min_size=1))
def test_any_string_title_gives_a_valid_page_that_shows_it(op, tmp_path_factory, title):
    path = tmp_path_factory.mktemp("page") / "page.html"
    expected = title.encode("utf-16", "surrogatepass").decode("utf-16", "replace")  # lone surrogates: U+FFFD
    _check_page(export.to_html(op, path, title=title), expected.replace("\r\n", "\n").replace("\r", "\n"))


def test_a_hostile_shape_name_in_the_operator_is_text_too(op, tmp_path):
    op.meta["shape"], old = "<!--<script>window.pwned=1</script>", op.meta.get("shape")
    try:
        text = _check_page(export.to_html(op, tmp_path / "page.html"), f"defop: {op.meta['shape']}, Ψ = tps")
    finally:
        op.meta["shape"] = old
    assert "window.pwned=1</script>" not in text


def test_a_lone_surrogate_is_replaced_not_a_0_byte_file(op, tmp_path):
    path = export.to_html(op, tmp_path / "page.html", title="a\ud800b\ud83d\ude42")
    _check_page(path, "a\ufffdb🙂")


@pytest.mark.parametrize("title", [5, 1.5, b"bytes", ["a"], {"t": 1}, object()])
def test_a_non_string_title_is_a_value_error_and_writes_nothing(op, tmp_path, title):
    path = tmp_path / "page.html"
    path.write_text("the page before")
    with pytest.raises(ValueError, match=r"^title must be a string, got "):
        export.to_html(op, path, title=title)
    assert path.read_text() == "the page before" and os.listdir(tmp_path) == ["page.html"]


def test_a_failed_write_leaves_the_old_page_and_no_temporary_file(op, tmp_path, monkeypatch):
    path = tmp_path / "page.html"
    path.write_text("the page before")

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OSError, match=r"cannot write path \(No space left on device\)") as info:
        export.to_html(op, path, title="t")
    assert info.value.filename == str(path)
    assert path.read_text() == "the page before" and os.listdir(tmp_path) == ["page.html"]


def test_a_missing_directory_names_the_page(op, tmp_path):
    path = tmp_path / "no" / "page.html"
    with pytest.raises(FileNotFoundError) as info:
        export.to_html(op, path)
    assert info.value.filename == str(path)


def test_script_json_escapes_what_ends_a_script():
    s = export.script_json({"t": "</script><!--<script>&\u2028\ud800"})
    assert not re.search(r"[<>&\u2028]|[^\x00-\x7f]", s)
    assert json.loads(s) == {"t": "</script><!--<script>&\u2028\ud800"}


# ------------------------------------------------------------------------------------------------ Chromium
@pytest.mark.browser
def test_hostile_pages_draw_the_mesh_and_run_no_injected_script(op, tmp_path):
    from test_browser_editor import chromium_page

    titles = [
        "<script>window.pwned=1</script>",
        "<!--<script>",
        "</script><img src=x onerror=window.pwned=1>",
        "</title><script>window.pwned=1</script>",
    ]
    with chromium_page(["--disable-3d-apis"]) as page:
        for k, title in enumerate(titles):
            path = export.to_html(op, tmp_path / f"page{k}.html", title=title)
            page.goto(path.as_uri())
            page.wait_for_function("() => window.defopEditor && window.defopEditor.st.X", timeout=20_000)
            seen = page.evaluate(
                "() => ({pwned: typeof window.pwned, title: document.title,"
                " shown: window.defopEditor.ui.title.textContent, X: Array.from(window.defopEditor.st.X),"
                " scripts: document.scripts.length, imgs: document.images.length})"
            )
            png = page.locator("canvas.defop-canvas").screenshot()
            assert seen["pwned"] == "undefined", title
            assert seen["title"] == title and seen["shown"] == title
            assert seen["scripts"] == 1 and seen["imgs"] == 0
            X = np.array(seen["X"]).reshape(-1, 2)
            np.testing.assert_allclose(X, op.mesh.V, atol=1e-6)  # the rest pose (8b): D(·, P) = x
            assert _drawn_pixels(png) > 500, title  # the mesh is drawn: the canvas is not blank
        assert not page.errors, page.errors


def _drawn_pixels(png):
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3).astype(int)
    colours, counts = np.unique(img, axis=0, return_counts=True)
    background = colours[np.argmax(counts)]
    return int(np.count_nonzero(np.abs(img - background).sum(axis=1) > 30))
