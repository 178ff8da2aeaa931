"""Every notebook is a lesson: a header naming what it reproduces and its run times, checked claims."""

from __future__ import annotations

import json
import pathlib
import re

import pytest

from defop import figures

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_is_a_notebook_per_figure():
    assert len(NOTEBOOKS) == 17  # 00_shapes .. 16_moving_handles


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_opens_with_a_header_and_checks_its_claims(path):
    cells = json.loads(path.read_text())["cells"]
    head = "".join(cells[0]["source"])
    assert cells[0]["cell_type"] == "markdown" and head.startswith("# "), "the first cell must be a markdown header"
    assert "Run time" in head and "fast" in head, "the header states full and fast run times"
    # the title is the book's sidebar entry on every page, including pages that load no MathJax: no maths in it
    assert "$" not in head.splitlines()[0], "the title line holds maths, which pages without MathJax cannot typeset"
    code = ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]
    assert any(src.startswith("# NBVAL_CHECK_OUTPUT") for src in code), "at least one checked claim"
    # outputs are stored from full runs (GitHub shows the real figures); the main job's normalisation numbers the
    # code cells 1, 2, ... (nbval needs counts on cells with stored outputs), and every checked cell has an output
    assert all(c.get("execution_count") for c in cells if c["cell_type"] == "code")
    checked = [c for c in cells if c["cell_type"] == "code" and "".join(c["source"]).startswith("# NBVAL_CHECK_OUTPUT")]
    assert all(c.get("outputs") for c in checked), "every # NBVAL_CHECK_OUTPUT cell has a stored output"


# development history belongs in git, not in a lesson: words that speak of issues, earlier versions or earlier runs
HISTORY = re.compile(
    r"\bissues?\b|#\d+|\bearlier\b|\bversions?\b|\bsessions?\b|\b20\d\d-\d\d(-\d\d)?\b|\bno longer\b|\bused to\b"
    r"|\bthe run before\b|\bprevious (?:run|version|output|notebook)s?\b|\bstored versions?\b"
    r"|\bbefore the (?:fix|change)\b|\bwas fixed\b",
    re.I,
)


def _prose(source):
    """A markdown cell without its run-time sentence (its "with the cache of a previous run" is a measurement)."""
    source = figures.CANONICAL_RE.sub("", source)
    return re.sub(r"`[^`]*`", "", source)  # code spans name things (a function may have "version" in its name)


def _outputs(cell):
    """The text a code cell's stored outputs show a reader: streams, plain text, markdown and error messages."""
    parts = []
    for out in cell.get("outputs", []):
        parts.append("".join(out.get("text", "")))
        data = out.get("data", {})
        parts += ["".join(data.get(kind, "")) for kind in ("text/plain", "text/markdown")]
        if out.get("output_type") == "error":
            parts.append(f"{out.get('ename', '')}: {out.get('evalue', '')}")
    return "\n".join(p for p in parts if p)


def _texts(cell):
    """What a reader sees of a cell: a markdown cell's prose, or a code cell's stored outputs."""
    return _prose("".join(cell["source"])) if cell["cell_type"] == "markdown" else _outputs(cell)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_no_markdown_cell_speaks_of_development_history(path):
    """Neither the prose nor what the code cells print (their stored outputs) speaks of issues or earlier runs."""
    cells = json.loads(path.read_text())["cells"]
    found = [
        (i, c["cell_type"], m.group(0), text[max(0, m.start() - 40) : m.end() + 40])
        for i, c in enumerate(cells)
        for text in [_texts(c)]
        for m in HISTORY.finditer(text)
    ]
    assert not found, f"{path.name}: history in a lesson (state what is, with numbers): {found}"


def test_the_history_check_catches_what_it_is_for():
    for text in (
        "The previous version of this notebook",
        "(issue #12)",
        "the issue measured 7x",
        "When the kink check was fixed (2026-11-24",
        "an earlier run on a busier machine",
    ):
        assert HISTORY.search(_prose(text)), text
    assert not HISTORY.search(_prose(figures.run_time_sentence(10, 5)))
    assert not HISTORY.search(_prose("each solve warm-started from the previous one"))
    printed = {"cell_type": "code", "outputs": [{"output_type": "stream", "text": ["issue 38's target, met: False\n"]}]}
    assert HISTORY.search(_texts(printed))
    shown = {"cell_type": "code", "outputs": [{"output_type": "execute_result", "data": {"text/plain": "see #7"}}]}
    assert HISTORY.search(_texts(shown))
