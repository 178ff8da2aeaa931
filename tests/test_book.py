"""The book (``make book``, issue 30): every page of the built site opened in headless Chromium.

The site is the one ``make book`` built when ``DEFOP_BOOK`` names it (``make test`` does), otherwise it is built
once per session into a temporary folder with ``docs/build.py``. It is served by ``http.server`` on 127.0.0.1 and
every request that leaves that server is aborted and recorded: the site must work offline. On every page: no
console error, no uncaught exception, no HTTP error, every image loaded (``naturalWidth > 0``), every link,
script, style sheet, image and frame of the site resolving to a file of the build (a ``#fragment`` to an id there),
and, on a page with maths, MathJax typeset every formula with no TeX error. On the landing page a handle of the
embedded octopus editor (``figures/octopus.html``) is dragged with the mouse and the canvas pixels must change.

Needs Debian's ``chromium`` and the Python ``playwright`` package (see tests/test_browser.py), and the ``docs``
extra (Sphinx, myst-nb, sphinx-book-theme) to build; skips with the reason when one is missing.
"""

from __future__ import annotations

import functools
import html
import io
import os
import re
import subprocess
import sys
import threading
import urllib.parse
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# the lessons every book has (the landing page's reading order); later lessons only add to it
LESSONS = ("00_shapes", "01_energies", "04_convergence", "07_octopus", "12_peers", "13_image_warping")
SUBPACKAGES = ("geometry", "scene", "variational", "operator", "training", "analysis", "view", "editor")


@pytest.fixture(scope="session")
def book(tmp_path_factory):
    """The built site's folder: $DEFOP_BOOK if set (make test), else a fresh build in a temporary folder."""
    given = os.environ.get("DEFOP_BOOK")
    if given:
        site = Path(given).resolve()
        assert (site / "index.html").is_file(), f"DEFOP_BOOK={given} has no index.html: run make book"
        return site
    pytest.importorskip("myst_nb", reason="the docs extra (sphinx, myst-nb) is not installed")
    site = tmp_path_factory.mktemp("book") / "site"
    res = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "build.py"), str(site)], capture_output=True, text=True, timeout=900
    )
    assert res.returncode == 0 and (site / "index.html").is_file(), res.stdout + res.stderr
    return site


@pytest.fixture(scope="session")
def server(book):
    """``http.server`` on a free port of 127.0.0.1 serving the site; yields its base URL."""

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(book)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    finally:
        httpd.shutdown()
        httpd.server_close()


@pytest.fixture(scope="module")
def browser():
    """Headless Debian Chromium through Playwright (skips when either is missing); module-scoped: a sync Playwright
    left running would make every later ``sync_playwright()`` of the session fail ("inside the asyncio loop")."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="the Python package playwright is not installed")
    from test_browser import CHROMIUM, CHROMIUM_ARGS

    if not (os.path.isfile(CHROMIUM) and os.access(CHROMIUM, os.X_OK)):
        pytest.skip(f"no Chromium at {CHROMIUM}")
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


def pages_of(book):
    """Every HTML page of the site, as paths relative to its root (the theme's template snippets excluded)."""
    return sorted(p.relative_to(book).as_posix() for p in book.rglob("*.html") if "_static" not in p.parts)


class Visit:
    """One browser context on the site: records console errors, page errors and every non-local request,
    which is aborted (the site must not need the network)."""

    def __init__(self, browser, base, viewport=(1280, 900)):
        self.base = base
        self.context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
        self.errors, self.external = [], []
        self.context.route("**/*", self._route)
        self.page = self.context.new_page()
        self.page.on("console", lambda m: m.type == "error" and self.errors.append(f"console: {m.text}"))
        self.page.on("pageerror", lambda e: self.errors.append(f"uncaught: {e}"))
        self.page.on("response", lambda r: r.status >= 400 and self.errors.append(f"HTTP {r.status}: {r.url}"))

    def _route(self, route):
        url = route.request.url
        if url.startswith((self.base, "data:", "blob:", "about:")):
            route.continue_()
        else:
            self.external.append(url)
            route.abort()

    def close(self):
        self.context.close()


def test_the_site_has_the_lessons_the_api_and_the_benchmarks(book):
    pages = set(pages_of(book))
    for name in LESSONS:
        assert f"notebooks/{name}.html" in pages, f"lesson {name} missing from the book"
    for nb in (ROOT / "notebooks").glob("[0-9]*.ipynb"):  # a lesson added later is in the book too
        assert f"notebooks/{nb.stem}.html" in pages, f"{nb.name} has no page in the book"
    for sub in SUBPACKAGES:
        assert f"generated/defop.{sub}.html" in pages, f"API reference of defop.{sub} missing"
    assert {"index.html", "api.html", "benchmarks.html", "editors/octopus.html"} <= pages
    index = (book / "index.html").read_text()
    order = [index.find(f'href="notebooks/{name}.html"') for name in LESSONS]
    assert -1 not in order and order == sorted(order), "the landing page does not list the lessons in reading order"
    assert "<iframe" in index and 'src="editors/octopus.html"' in index
    # the stored outputs are shown (nothing was executed to make them): the octopus lesson has its figure
    assert re.search(r'<img [^>]*src="../_images/', (book / "notebooks" / "07_octopus.html").read_text())
    # the benchmarks page is benchmarks/README.md
    first = (ROOT / "benchmarks" / "README.md").read_text().splitlines()[0].lstrip("# ").strip()
    assert html.escape(first) in (book / "benchmarks.html").read_text()
    # MathJax is served by the site itself, at the vendored version
    assert (book / "_static" / "mathjax" / "tex-chtml.js").is_file()
    assert "_static/mathjax/tex-chtml.js" in index


def _local_targets(page, base):
    """URLs of the site that the page refers to: links, scripts, styles, images, frames (fragments kept)."""
    urls = page.evaluate(
        """() => [...document.querySelectorAll('a[href], link[href], script[src], img[src], iframe[src]')]
              .map(e => e.href || e.src)"""
    )
    return sorted({u for u in urls if u.startswith(base)})


def _resolves(book, base, url, ids_cache):
    """The file an URL of the site names exists in the build, and its fragment is an id of that page."""
    parts = urllib.parse.urlsplit(url)
    rel = urllib.parse.unquote(parts.path)[len(urllib.parse.urlsplit(base).path) :]
    target = book / rel
    if rel == "" or rel.endswith("/"):
        target = target / "index.html"
    if not target.is_file():
        return f"{url}: no file {target.relative_to(book)} in the build"
    if parts.fragment and target.suffix == ".html":
        if target not in ids_cache:
            ids_cache[target] = set(re.findall(r'\bid="([^"]+)"', target.read_text(errors="replace")))
        if urllib.parse.unquote(parts.fragment) not in ids_cache[target]:
            return f"{url}: no id {parts.fragment!r} on {target.relative_to(book)}"
    return None


def _check_maths(page):
    """On a page with maths: wait for MathJax; every formula typeset, none in error. Returns the formula count."""
    n_math = page.evaluate("() => document.querySelectorAll('.math').length")
    if n_math == 0:
        return 0
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    try:
        page.wait_for_function("() => window.MathJax && MathJax.startup && MathJax.startup.promise", timeout=15_000)
    except PlaywrightTimeout:
        raise AssertionError(f"{n_math} formulas but MathJax did not start within 15 s") from None
    page.evaluate("() => MathJax.startup.promise")
    raw = page.evaluate(
        "() => [...document.querySelectorAll('.math')].filter(e => !e.querySelector('mjx-container'))"
        ".map(e => e.textContent.slice(0, 60))"
    )
    errors = page.evaluate("() => [...document.querySelectorAll('mjx-merror')].map(e => e.textContent)")
    assert not raw, f"{len(raw)} of {n_math} formulas not typeset by MathJax: {raw[:3]}"
    assert not errors, f"TeX errors: {errors[:5]}"
    return n_math


def _check_images(page):
    """Every <img> loaded (lazy ones are made eager first). Returns the number of images."""
    page.evaluate("() => document.querySelectorAll('img[loading=lazy]').forEach(i => { i.loading = 'eager'; })")
    page.wait_for_function("() => [...document.images].every(i => i.complete)", timeout=15_000)
    broken = page.evaluate("() => [...document.images].filter(i => !(i.naturalWidth > 0)).map(i => i.src)")
    assert not broken, f"images that did not load: {broken}"
    return page.evaluate("() => document.images.length")


@pytest.mark.browser
def test_every_page_offline_no_errors_maths_images_links(book, server, browser):
    pages = pages_of(book)
    visit = Visit(browser, server)
    ids_cache, problems, n_math, n_img = {}, [], {}, 0
    try:
        for rel in pages:
            visit.errors.clear()
            visit.page.goto(server + rel, wait_until="load")
            try:
                n_math[rel] = _check_maths(visit.page)
                n_img += _check_images(visit.page)
            except AssertionError as exc:
                problems.append(f"{rel}: {exc}")
            for url in _local_targets(visit.page, server):
                if (why := _resolves(book, server, url, ids_cache)) is not None:
                    problems.append(f"{rel}: {why}")
            visit.page.evaluate("() => document.fonts.ready.then(() => true)")  # MathJax's and the theme's fonts
            visit.page.wait_for_timeout(50)  # late console errors (frames) are reported on this page
            problems += [f"{rel}: {e}" for e in visit.errors]
        external = list(visit.external)
    finally:
        visit.close()
    problems += [f"the site asked the network for {url}" for url in sorted(set(external))]
    assert not problems, "\n".join(problems[:40])
    # the checks ran on something: maths on the lessons and the landing page, the lessons' figures
    assert n_math["index.html"] > 0 and n_math["notebooks/01_energies.html"] > 0
    assert n_img >= 10
    assert len(pages) >= 20


def _canvas_pixels(locator):
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(locator.screenshot())).convert("RGB"), dtype=np.int16)


@pytest.mark.browser
def test_drag_the_embedded_octopus(book, server, browser):
    """The editor page inside the landing page's iframe: a mouse drag from moving handle 0 moves the mesh."""
    visit = Visit(browser, server, viewport=(1280, 1000))
    try:
        page = visit.page
        page.goto(server + "index.html", wait_until="load")
        page.locator("#octopus-editor-frame").scroll_into_view_if_needed()
        frame = page.frame_locator("#octopus-editor-frame")
        inner = next(f for f in page.frames if f.url.endswith("editors/octopus.html"))
        inner.wait_for_function("() => window.defopEditor && window.defopEditor.st.X", timeout=30_000)
        canvas = frame.locator("canvas.defop-canvas")
        canvas.scroll_into_view_if_needed()
        page.wait_for_timeout(200)
        before = _canvas_pixels(canvas)
        X0 = np.array(inner.evaluate("() => Array.from(window.defopEditor.st.X)"))
        box = canvas.bounding_box()  # in the landing page's viewport
        u, v = inner.evaluate("() => window.defopEditor.handleScreen(0)")
        x0, y0 = box["x"] + u, box["y"] + v
        assert 0 <= x0 < 1280 and 0 <= y0 < 1000, f"handle 0 at ({x0:.0f}, {y0:.0f}) is off screen"
        page.mouse.move(x0, y0)
        page.mouse.down()
        page.mouse.move(x0 + 45, y0 - 35, steps=12)  # intermediate pointer moves, as a hand makes
        page.mouse.up()
        page.wait_for_timeout(200)
        after = _canvas_pixels(canvas)
        X1 = np.array(inner.evaluate("() => Array.from(window.defopEditor.st.X)"))
        errors, external = list(visit.errors), list(visit.external)
    finally:
        visit.close()
    assert not errors, errors
    assert not external, external
    assert before.shape == after.shape
    changed = np.mean(np.any(np.abs(after - before) > 16, axis=-1))
    assert changed > 0.002, f"the canvas did not change after the drag ({changed:.2%} of its pixels)"
    moved = np.linalg.norm((X1 - X0).reshape(-1, 2), axis=1)
    assert moved.max() > 0, "the mesh did not move"
