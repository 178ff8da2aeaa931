"""The main job's schedule (defop.figures.schedule, pure) and notebooks run side by side (two tiny notebooks)."""

from __future__ import annotations

import json
import os

import nbformat
import pytest
from hypothesis import given
from hypothesis import strategies as st
from nbformat.v4 import new_code_cell, new_notebook

from defop import figures
from defop.figures import schedule


def test_longest_first_ties_in_name_order():
    seconds = {"00_a": 5.0, "01_b": 300.0, "02_c": 5.0, "03_d": 60.0}
    assert schedule.order(list(seconds), seconds) == ["01_b", "03_d", "00_a", "02_c"]


def test_lessons_that_measure_times_run_alone_after_the_others():
    seconds = {"00_a": 5.0, "10_timings": 300.0, "02_c": 50.0}
    assert schedule.plan(list(seconds), seconds, 2) == (["02_c", "00_a"], ["10_timings"])
    assert schedule.plan(list(seconds), seconds, 1) == (list(seconds), [])  # one at a time: name order
    assert "10_timings" in schedule.ALONE


def test_the_makespan_of_list_scheduling():
    assert schedule.makespan([300, 60, 50, 5], 1) == 415
    assert schedule.makespan([300, 60, 50, 5], 2) == 300  # the long one alone, the three others beside it
    assert schedule.makespan([5, 50, 60, 300], 2) == 350  # name order: the long one starts last
    assert schedule.makespan([10], 2, busy=[30]) == 30
    assert schedule.makespan([], 2) == 0


def test_the_eta_counts_what_the_running_lessons_have_left():
    assert schedule.eta([20.0], [(100.0, 70.0), (10.0, 15.0)], 2) == 30.0  # 30 s left; the overdue one counts 0


@given(st.lists(st.floats(0, 1e4), max_size=12), st.integers(1, 4))
def test_the_makespan_is_bounded_by_the_work(durations, jobs):
    span = schedule.makespan(durations, jobs)
    assert max(durations, default=0) <= span + 1e-6
    assert sum(durations) / jobs <= span + 1e-6 <= sum(durations) + 1e-6


def test_overlaps():
    spans = {"a": (0, 10), "b": (5, 20), "c": (10, 12)}
    assert schedule.overlaps(spans) == {"a": ["b"], "b": ["a", "c"], "c": ["b"]}


def test_expected_seconds_read_the_record(tmp_path):
    record = {"full": {"notebooks": {"a": {"seconds": 10.0, "cold": 100.0}, "b": {"seconds": 30.0}}}}
    path = tmp_path / "runtimes.json"
    path.write_text(json.dumps(record))
    assert schedule.expected_seconds(["a", "b", "c"], path, "full") == {"a": 10.0, "b": 30.0, "c": 20.0}
    assert schedule.expected_seconds(["a", "b"], record, "full", cold=True) == {"a": 100.0, "b": 30.0}
    assert schedule.expected_seconds(["a"], tmp_path / "none.json", "fast") == {"a": schedule.UNKNOWN_SECONDS}


def test_jobs_share_out_the_cores():
    assert schedule.default_jobs(1) == 1 and schedule.default_jobs(2) == 2 and schedule.default_jobs(16) == 2
    assert schedule.inner_jobs(1, 2) is None  # one at a time: the lesson's own default (every core)
    assert schedule.inner_jobs(2, 2) == 1 and schedule.inner_jobs(2, 8) == 4 and schedule.inner_jobs(2, 1) == 1
    assert schedule.cores() >= 1


def _write(folder, name, source):
    nb = new_notebook(cells=[new_code_cell(source)])
    nb.metadata["kernelspec"] = {"display_name": "Python 3", "language": "python", "name": "python3"}
    nbformat.write(nb, folder / f"{name}.ipynb")


def test_notebooks_side_by_side(tmp_path, monkeypatch):
    """Two notebooks at once, each kernel with one solver worker; the report in name order, both recorded with the
    notebook beside them; the one that stored a cache entry is partial, the other warm."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("DEFOP_N_JOBS", raising=False)
    folder = tmp_path / "nbs"
    folder.mkdir()
    probe = "import os, time\nfrom defop.figures import schedule\ntime.sleep(2)\n"
    probe += "assert os.environ['DEFOP_N_JOBS'] == os.environ['OMP_NUM_THREADS'] == str(schedule.inner_jobs(2))\n"
    store = "from defop.training import cache as cm\nimport numpy as np\n"
    store += "cm.open_cache().store('gt', 'a' * 20, {'X': np.zeros(2)})\n"
    _write(folder, "00_a", probe + store)
    _write(folder, "01_b", probe)
    lines = []
    record = tmp_path / "runtimes.json"
    report = figures.regenerate(fast=True, directory=folder, log=lines.append, record=record, jobs=2)
    assert [(r["name"], r["ok"], r["cache"]) for r in report] == [("00_a", True, "partial"), ("01_b", True, "warm")]
    assert report[0]["computed"] == ["gt-" + "a" * 20 + ".npz"]
    assert report[0]["start"] < report[1]["end"] and report[1]["start"] < report[0]["end"]  # side by side
    entry = json.loads(record.read_text())["fast"]
    assert entry["jobs"] == 2 and entry["wall"] > 0
    assert entry["notebooks"]["00_a"]["beside"] == ["01_b"] and entry["notebooks"]["01_b"]["beside"] == ["00_a"]
    assert any("side by side" in line for line in lines) and "about" in lines[0]
    assert os.listdir(tmp_path / "cache") == ["gt-" + "a" * 20 + ".npz"]  # no lock or journal left


def test_jobs_must_be_a_positive_integer(tmp_path):
    with pytest.raises(ValueError, match="jobs"):
        figures.regenerate(fast=True, directory=tmp_path, record=None, jobs=0)


def test_prints_split_into_messages_are_stored_as_one_output():
    """How a kernel splits a cell's prints into messages depends on its timing (side by side, under load)."""
    split = [
        {"output_type": "stream", "name": "stdout", "text": "a\n"},
        {"output_type": "stream", "name": "stdout", "text": ["b\n", "c\n"]},
        {"output_type": "stream", "name": "stderr", "text": "w\n"},
        {"output_type": "stream", "name": "stdout", "text": "d\n"},
    ]
    nb = new_notebook(cells=[new_code_cell("print('a')")])
    nb.cells[0].outputs = [nbformat.from_dict(o) for o in split]
    one = new_notebook(cells=[new_code_cell("print('a')")])
    one.cells[0].outputs = [nbformat.from_dict(o) for o in [{**split[0], "text": "a\nb\nc\n"}, split[2], split[3]]]
    assert figures.normalise(nb).cells[0].outputs == figures.normalise(one).cells[0].outputs
    assert [o["text"] for o in figures.normalise(nb).cells[0].outputs] == ["a\nb\nc\n", "w\n", "d\n"]


def test_a_whole_run_records_its_wall_time_as_the_total(tmp_path):
    path = tmp_path / "runtimes.json"
    report = [dict(name="00_a", seconds=5.0, ok=True, cache="cold", cpu=4.0, start=0.0, end=5.0)]
    figures.write_runtimes(report, "full", path, jobs=2, wall=7.0, whole="cold")
    figures.write_runtimes([{**report[0], "cache": "partial"}], "full", path, jobs=2, wall=3.0)  # a part: kept
    entry = json.loads(path.read_text())["full"]
    assert entry["totals"] == {"cold": 7.0} and entry["wall"] == 3.0 and entry["notebooks"]["00_a"]["cpu"] == 4.0


def test_a_lesson_waits_on_the_lessons_that_computed_what_it_read():
    report = [
        dict(name="09_g", computed=["op-1.npz", "gt-2.npz"], read=["op-1.npz"]),
        dict(name="12_p", computed=["gt-3.npz"], read=["op-1.npz", "gt-3.npz", "gt-9.npz"]),
        dict(name="07_o", computed=[], read=["gt-2.npz", "gt-3.npz"]),
    ]
    after = schedule.producers(report)
    assert after == {"12_p": ["09_g"], "07_o": ["09_g", "12_p"]}  # its own entries and unknown ones do not count
    queue = ["12_p", "07_o", "00_a"]
    assert schedule.next_ready(queue, {*queue, "09_g"}, after, running=["09_g"]) == 2
    assert schedule.next_ready(["12_p", "07_o"], {"12_p", "07_o", "09_g"}, after, running=["09_g"]) is None
    assert schedule.next_ready(["12_p", "07_o"], {"12_p", "07_o"}, after, running=[]) == 0
    cycle = {"a": ["b"], "b": ["a"]}
    assert schedule.next_ready(["a", "b"], {"a", "b"}, cycle, running=[]) == 0  # a cycle: the first starts


@given(st.lists(st.lists(st.integers(0, 7), max_size=3), min_size=1, max_size=8), st.integers(1, 3))
def test_no_lesson_starts_before_what_it_waits_on_has_ended(deps, jobs):
    """A simulated run: whatever the record says (cycles included) every lesson starts once, and one that waits on
    an earlier-ending lesson of an acyclic record never starts before it has ended."""
    names = [f"{i:02d}" for i in range(len(deps))]
    after = {n: sorted({names[j] for j in d if j < len(names)} - {n}) for n, d in zip(names, deps, strict=True)}
    queue, running, ended, started, t = list(names), {}, {}, {}, 0
    while queue or running:
        while queue and len(running) < jobs:
            i = schedule.next_ready(queue, {*queue, *running}, after, running)
            if i is None:
                break
            name = queue.pop(i)
            started[name], running[name] = t, t + 1 + int(name) % 3
        name = min(running, key=running.get)  # the first to end
        t = running.pop(name)
        ended[name] = t
    assert sorted(started) == names
    acyclic = all(a < n for n, deps_ in after.items() for a in deps_)
    if acyclic:
        assert all(started[n] >= ended[a] for n, deps_ in after.items() for a in deps_)


def test_a_run_from_an_empty_cache_records_who_waits_on_whom(tmp_path):
    path = tmp_path / "runtimes.json"
    report = [
        dict(name="00_a", seconds=5.0, ok=True, cache="partial", computed=["gt-1.npz"], read=[], start=0.0, end=5.0),
        dict(name="01_b", seconds=5.0, ok=True, cache="warm", computed=[], read=["gt-1.npz"], start=0.0, end=5.0),
    ]
    report[0]["cpu"] = 4.0
    figures.write_runtimes(report, "full", path, jobs=2, wall=7.0, whole="cold")
    assert schedule.recorded_after(["00_a", "01_b"], path, "full") == {"01_b": ["00_a"]}
    # the next run from an empty cache starts longest first by the work each lesson did there (wall: 5.0 each)
    assert schedule.expected_seconds(["00_a", "01_b"], path, "full", cold=True) == {"00_a": 4.0, "01_b": 5.0}
    assert schedule.recorded_after(["01_b"], path, "full") == {}  # 00_a does not run
    warm = [{**r, "cache": "warm", "computed": [], "read": ["gt-1.npz"]} for r in report]
    figures.write_runtimes(warm, "full", path, jobs=2, wall=2.0, whole="warm")  # a warm run keeps the lists
    assert json.loads(path.read_text())["full"]["notebooks"]["01_b"]["after"] == ["00_a"]
    assert schedule.expected_seconds(["00_a"], path, "full", cold=True) == {"00_a": 4.0}
    # a clean run (each lesson from an empty cache of its own) keeps both: its lessons share nothing
    clean = [{**r, "cache": "cold", "cpu": 50.0, "computed": ["gt-1.npz"], "read": []} for r in report]
    figures.write_runtimes(clean, "full", path, jobs=2, wall=60.0, whole="cold")
    assert schedule.recorded_after(["00_a", "01_b"], path, "full") == {"01_b": ["00_a"]}
    assert schedule.expected_seconds(["00_a"], path, "full", cold=True) == {"00_a": 4.0}
