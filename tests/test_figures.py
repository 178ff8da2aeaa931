"""The main job (``python -m defop figures``): progress, failures, timeouts, the timing record, storing."""

from __future__ import annotations

import copy
import io
import json
import os
import time

import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook, new_output

from defop import figures
from defop.__main__ import main

HEADER = "# A lesson\n\n**Run time:** full 10 s, fast 5 s (measured by the main job).\n"


def _write(folder, name, *sources):
    nb = new_notebook(cells=[new_markdown_cell(HEADER)] + [new_code_cell(s) for s in sources])
    nb.metadata["kernelspec"] = {"display_name": "Python 3", "language": "python", "name": "python3"}
    path = folder / f"{name}.ipynb"
    nbformat.write(nb, path)
    return path


@pytest.fixture
def quiet_log():
    lines = []
    return lines, lines.append


def test_a_failing_notebook_is_reported_and_the_others_still_run(tmp_path, quiet_log):
    lines, log = quiet_log
    _write(tmp_path, "01_bad", "x = 1", "# NBVAL_CHECK_OUTPUT\nraise ValueError('boom')")
    _write(tmp_path, "02_good", "print('fine')")
    record = tmp_path / "runtimes.json"
    report = figures.regenerate(fast=True, directory=tmp_path, log=log, record=record)
    assert [(r["name"], r["ok"]) for r in report] == [("01_bad", False), ("02_good", True)]
    err = report[0]["error"]
    assert "01_bad" in err and "cell 2" in err and "raise ValueError('boom')" in err and "boom" in err
    # one line as each notebook starts and ends
    assert sum("started" in ln for ln in lines) == 2 and sum(" ok " in ln for ln in lines) == 1
    assert any("FAILED" in ln and "01_bad" in ln for ln in lines)
    saved = json.loads(record.read_text())["fast"]
    assert saved["notebooks"]["01_bad"]["ok"] is False and saved["notebooks"]["02_good"]["ok"] is True
    assert saved["machine"]["cores"] >= 1 and saved["date"]


def test_the_command_exits_non_zero_when_a_notebook_fails(tmp_path, monkeypatch, capsys):
    _write(tmp_path, "01_bad", "1 / 0")
    monkeypatch.setattr(figures, "NOTEBOOKS", tmp_path)
    assert main(["figures", "--fast", "--no-record"]) == 1
    assert "ZeroDivisionError" in capsys.readouterr().out
    _write(tmp_path, "01_bad", "1 / 1")
    assert main(["figures", "--fast", "--no-record"]) == 0


def test_a_hanging_cell_fails_fast_naming_notebook_and_cell(tmp_path):
    path = _write(tmp_path, "03_slow", "import time", "time.sleep(120)  # a hang")
    t0 = time.perf_counter()
    with pytest.raises(figures.NotebookError, match=r"03_slow, cell 2 \('time.sleep\(120\)  # a hang'\) timed out"):
        figures.run_notebook(path, fast=True, timeout=3, progress=None)
    assert time.perf_counter() - t0 < 60


def test_progress_goes_to_the_terminal_and_is_not_stored(tmp_path):
    bar = (
        "from defop.training.batch import progress\n"
        "bar = progress(5, 'sample solves', True)\n"
        "for _ in range(5):\n    bar.update(1)\nbar.close()\nprint('trained')"
    )
    path = _write(tmp_path, "04_train", bar)
    terminal = io.StringIO()
    figures.run_notebook(path, fast=True, store=True, progress=terminal)
    assert "sample solves:   0%" in terminal.getvalue()
    outputs = nbformat.read(path, as_version=4).cells[1].outputs
    assert [o.get("text") for o in outputs] == ["trained\n"], "only the print is stored, no frozen bar"


def test_normalise_drops_churn_and_keeps_outputs():
    nb = new_notebook(cells=[new_code_cell("display(w)", execution_count=7)])
    nb.metadata.update(
        kernelspec={"display_name": "Python 3", "language": "python", "name": "python3"},
        language_info={"name": "python", "version": "3.11.7"},
        widgets={"application/vnd.jupyter.widget-state+json": {"state": {}}},
    )
    cell = nb.cells[0]
    cell.metadata["execution"] = {"iopub.status.busy": "2026-11-23T10:39:05.540960Z"}
    picture = {"image/png": "iVBOR", "text/plain": "Handle editor: bar", figures.WIDGET_VIEW: {"model_id": "ab12"}}
    bar = {"text/plain": "bootstrap solves:   0%|          | 0/5 [00:00<?, ?it/s]", figures.WIDGET_VIEW: {}}
    cell.outputs = [
        new_output("display_data", data=picture),
        new_output("display_data", data=bar),
        new_output("stream", name="stdout", text="kept\n"),
    ]
    out = figures.normalise(copy.deepcopy(nb))
    assert "widgets" not in out.metadata and "version" not in out.metadata.language_info
    assert out.metadata.kernelspec == nb.metadata.kernelspec
    assert out.cells[0].execution_count == 1 and "execution" not in out.cells[0].metadata  # numbered as a run-all
    assert out.cells[0].id == nb.cells[0].id
    kinds = [o.get("data", {}).keys() or o.text for o in out.cells[0].outputs]
    assert kinds == [{"image/png", "text/plain"}, "kept\n"]
    assert figures.normalise(copy.deepcopy(out)) == out


def test_a_regeneration_that_changes_nothing_changes_no_byte(tmp_path):
    path = _write(tmp_path, "05_same", "import sys\nprint(sys.version_info[0])", "1 + 1")
    figures.run_notebook(path, fast=True, store=True, progress=None)
    first = path.read_bytes()
    figures.run_notebook(path, fast=True, store=True, progress=None)
    assert path.read_bytes() == first
    assert figures.normalise_files([path]) == []


def test_runtimes_record_keeps_other_modes_and_notebooks(tmp_path):
    path = tmp_path / "runtimes.json"
    figures.write_runtimes([dict(name="00_a", seconds=12.34, ok=True)], "full", path)
    figures.write_runtimes([dict(name="01_b", seconds=3.0, ok=True)], "full", path)
    record = figures.write_runtimes([dict(name="00_a", seconds=2.0, ok=False)], "fast", path)
    assert record["full"]["notebooks"] == {"00_a": {"seconds": 12.3, "ok": True}, "01_b": {"seconds": 3.0, "ok": True}}
    assert record["fast"]["notebooks"] == {"00_a": {"seconds": 2.0, "ok": False}}
    assert json.loads(path.read_text()) == record


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("**Run time:** full 95 s, fast 20 s (measured by the main job).", (95, 20)),
        ("**Run time:** full 8.4 min, fast 1,200 s", (504, 1200)),
        ("**Run time** on the 2-core machine: full ≈ 10 s, fast (`DEFOP_FAST=1`) ≈ 15 s.", (10, 15)),
        ("**Run time:** full ≈ 3.6 min (1,000 ground-truth solves), fast ≈ 13 s.", (216, 13)),
        ("**Run time:** full ≈ 21 s after notebooks (it\nreuses their ground truths), fast ≈ 16 s.", (21, 16)),
        ("the readout. **Run time:** ≈ 3 s (fast ≈ 8 s).", (3, 8)),
        ("no stated time", None),
    ],
)
def test_parse_run_time(text, expected):
    got = figures.parse_run_time(text)
    assert got == (None if expected is None else pytest.approx(expected))


def test_update_stated_times_rewrites_headers_and_tables(tmp_path):
    (tmp_path / "notebooks").mkdir()
    nb = _write(tmp_path / "notebooks", "00_a", "1")
    legacy = nbformat.read(nb, as_version=4)
    legacy.cells[0].source = "# A\n**Writes:** x. **Run time:** full ≈ 3.6 min (many solves), fast ≈ 13 s.\n\nMath."
    nbformat.write(legacy, nb)
    (tmp_path / "notebooks" / "README.md").write_text(
        "| notebook | paper | full | fast |\n|---|---|---|---|\n| `00_a` | Fig. 1 | ≈ 3.6 min | ≈ 13 s |\n\n"
        "All of them: **Run time:** full 1 s, fast 1 s (measured by the main job).\n"
    )
    (tmp_path / "README.md").write_text("All of it. **Run time of `make figures`:** full 5 min, fast 2 min.\n")
    record = tmp_path / "runtimes.json"
    figures.write_runtimes([dict(name="00_a", seconds=502.0, ok=True)], "full", record)
    figures.write_runtimes([dict(name="00_a", seconds=21.0, ok=True)], "fast", record)
    changed = figures.update_stated_times(record, root=tmp_path)
    assert len(changed) == 3
    assert figures.stated_times(tmp_path) == {
        "00_a": (502.0, 21.0),
        "table:00_a": (502.0, 21.0),
        "total": (502.0, 21.0),
        "total:notebooks/README.md": (502.0, 21.0),
    }
    head = nbformat.read(nb, as_version=4).cells[0].source
    assert (
        "**Run time** (measured by the main job): full 502 s with the cache of a previous run, not measured from an "
        "empty cache; fast 21 s with the cache, not measured from an empty cache." in head
    ) and head.endswith("\n\nMath.")
    assert figures.update_stated_times(record, root=tmp_path) == []


def _recorded():
    if not figures.RUNTIMES.exists():
        pytest.skip("no figures/runtimes.json yet: the main job (make figures) writes it")
    record = json.loads(figures.RUNTIMES.read_text())
    return {mode: {k: v["seconds"] for k, v in record.get(mode, {}).get("notebooks", {}).items()} for mode in record}


def test_stated_run_times_agree_with_the_main_jobs_record_within_a_factor_of_2():
    recorded = _recorded()
    full, fast = recorded.get("full", {}), recorded.get("fast", {})
    stated = figures.stated_times()
    bad = []
    for key, times in stated.items():
        name = key.removeprefix("table:")
        if key.startswith("total"):
            measured = (sum(full.values()), sum(fast.values())) if full and fast else None
        else:
            measured = (full.get(name), fast.get(name))
        assert times is not None, f"{key}: no machine-readable 'Run time: full … s, fast … s' sentence"
        for mode, said, took in zip(("full", "fast"), times, measured or (None, None)):
            if took is not None and not 0.5 <= said / max(took, 1.0) <= 2.0:
                bad.append(f"{key} {mode}: states {said:.0f} s, the main job took {took:.0f} s")
    assert not bad, "stated run times disagree with figures/runtimes.json (python -m defop runtimes):\n" + "\n".join(
        bad
    )


def test_notebooks_stored_by_the_main_job_are_normalised():
    stored = _recorded().get("full", {})
    for path in figures.notebooks():
        if path.stem in stored:
            text = path.read_text()
            nb = nbformat.reads(text, as_version=4)
            assert nbformat.writes(figures.normalise(nb)) + "\n" == text, f"{path.name}: run make normalise"


def test_runtimes_record_keeps_cold_and_warm_times_apart(tmp_path):
    path = tmp_path / "runtimes.json"
    path.write_text(json.dumps({"full": {"notebooks": {"00_a": {"seconds": 9.0, "ok": True}}}}))  # an older record
    figures.write_runtimes([dict(name="00_a", seconds=300.0, ok=True, cache="cold")], "full", path)
    figures.write_runtimes([dict(name="00_a", seconds=7.0, ok=True, cache="partial")], "full", path)
    record = figures.write_runtimes([dict(name="00_a", seconds=11.0, ok=True, cache="warm")], "full", path)
    assert record["full"]["notebooks"]["00_a"] == {
        "seconds": 11.0,
        "ok": True,
        "cache": "warm",
        "cold": 300.0,
        "warm": 11.0,
    }
    figures.write_runtimes([dict(name="00_a", seconds=99.0, ok=False, cache="cold")], "full", path)
    warm, cold = figures.recorded_times(path, "full")
    assert warm == {"00_a": 11.0} and cold == {"00_a": 300.0}  # a failed run measures nothing


def test_the_run_time_sentence_states_both_caches_and_reads_back():
    sentence = figures.run_time_sentence(11.0, 8.0, 250.0, None)
    assert "full 11 s with the cache of a previous run, 250 s from an empty cache" in sentence
    assert "fast 8 s with the cache, not measured from an empty cache" in sentence
    text = f"# A\n**Writes:** x. {sentence}.\n\nMath."
    assert figures.parse_run_time(text) == (11.0, 8.0)
    assert figures.parse_run_time(text, cold=True) == (250.0, None)
    assert figures.parse_run_time("**Run time:** full 95 s, fast 20 s.", cold=True) is None
    again = figures.replace_run_time(text, figures.run_time_sentence(12.0, 9.0, 700.0, 30.0))
    assert again.count("Run time") == 1 and again.endswith(".\n\nMath.") and "11.7 min from an empty cache" in again


def test_a_clean_run_gives_each_notebook_an_empty_cache_and_keeps_its_entries(tmp_path, monkeypatch, quiet_log):
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "op-old.npz").write_text("an entry of another run")
    monkeypatch.setenv("DEFOP_CACHE", str(cache))
    monkeypatch.setattr(figures, "_clean", lambda log: None)  # keep the real figures/ (the test writes none)
    folder = tmp_path / "nbs"
    folder.mkdir()
    store = "import os, pathlib\nd = pathlib.Path(os.environ['DEFOP_CACHE'])\n"
    for name in ("01_a", "02_b"):  # each stores its entry when missing, as defop's cache users do
        entry = f"op-{name[-1]}.npz"
        _write(
            folder,
            name,
            store + f"p = d / {entry!r}\nif not p.exists():\n    p.write_text('x')\nprint(len(list(d.iterdir())))",
        )
    lines, log = quiet_log
    report = figures.regenerate(fast=True, clean=True, directory=folder, log=log, record=None)
    assert [(r["ok"], r["cache"]) for r in report] == [(True, "cold"), (True, "cold")], lines
    assert sorted(f.name for f in cache.iterdir()) == ["op-a.npz", "op-b.npz", "op-old.npz"]
    assert os.environ["DEFOP_CACHE"] == str(cache)
    (cache / "op-b.npz").unlink()
    report = figures.regenerate(fast=True, directory=folder, log=log, record=None)
    assert [r["cache"] for r in report] == ["warm", "partial"]
