"""Every notebook is a lesson: a header naming what it reproduces and its run times, checked claims."""

from __future__ import annotations

import json
import pathlib

import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_is_a_notebook_per_figure():
    assert len(NOTEBOOKS) == 14


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_opens_with_a_header_and_checks_its_claims(path):
    cells = json.loads(path.read_text())["cells"]
    head = "".join(cells[0]["source"])
    assert cells[0]["cell_type"] == "markdown" and head.startswith("# "), "the first cell must be a markdown header"
    assert "Run time" in head and "fast" in head, "the header states full and fast run times"
    code = ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]
    assert any(src.startswith("# NBVAL_CHECK_OUTPUT") for src in code), "at least one checked claim"
    # outputs are stored from full runs (GitHub shows the real figures); the main job's normalisation numbers the
    # code cells 1, 2, ... (nbval needs counts on cells with stored outputs), and every checked cell has an output
    assert all(c.get("execution_count") for c in cells if c["cell_type"] == "code")
    checked = [c for c in cells if c["cell_type"] == "code" and "".join(c["source"]).startswith("# NBVAL_CHECK_OUTPUT")]
    assert all(c.get("outputs") for c in checked), "every # NBVAL_CHECK_OUTPUT cell has a stored output"
