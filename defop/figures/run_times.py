"""The main job's timing record (``figures/runtimes.json``) and the run times the documentation states.

Each notebook's header, the table in ``notebooks/README.md`` and ``README.md`` state run times in one canonical,
machine-readable sentence (:func:`run_time_sentence`); :func:`update_stated_times` writes the recorded times into
them and :func:`stated_times` reads them back.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import re
from pathlib import Path

from .paths import ROOT, RUNTIMES, notebooks
from .schedule import overlaps, producers

__all__ = [
    "machine_info",
    "write_runtimes",
    "RUN_TIME_RE",
    "CANONICAL_RE",
    "format_seconds",
    "parse_run_time",
    "replace_run_time",
    "run_time_sentence",
    "stated_times",
    "update_stated_times",
    "recorded_times",
]


def machine_info():
    """What the run times were measured on: CPU, cores, Python, OS and the key package versions."""
    from importlib.metadata import PackageNotFoundError, version

    cpu = platform.processor()
    try:
        text = Path("/proc/cpuinfo").read_text()
        cpu = re.search(r"^model name\s*:\s*(.+)$", text, re.M).group(1).strip()
    except (OSError, AttributeError):
        pass
    packages = {}
    for name in ("numpy", "scipy", "ipykernel", "nbclient"):
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            pass
    return dict(cpu=cpu, cores=os.cpu_count(), python=platform.python_version(), os=platform.platform(), **packages)


def write_runtimes(report, mode, path=RUNTIMES, jobs=1, wall=None, whole=None):
    """Merge a run's seconds into the timing record (other modes and notebooks are kept).

    Parameters
    ----------
    report : list of dict
        From :func:`regenerate`.
    mode : {"full", "fast"}
    path : path
    jobs : int
        Notebooks that ran side by side.
    wall : float, optional
        The run's wall seconds, start to end.
    whole : {"cold", "warm"}, optional
        The run was of every notebook, from an empty cache (``"cold"``) or with the cache of a previous run
        (``"warm"``): its wall seconds are also recorded as ``totals[whole]``, the time :func:`update_stated_times`
        states for the whole job (kept while a later run is not whole).

    Returns
    -------
    record : dict
        ``{mode: {"date", "machine", "load", "jobs", "wall", "notebooks": {name: {"seconds", "cpu", "beside", "after",
        "ok", "cache", "cold", "warm"}}}}``: ``jobs`` notebooks ran side by side (1: one after another) and the run
        took ``wall`` seconds; per notebook, ``seconds`` (wall), ``cpu`` (its kernel's and workers' CPU seconds),
        ``beside`` (the notebooks that ran beside it), ``ok`` and ``cache`` are the last run's; ``after`` the last
        whole run's from an empty cache (the notebooks that computed a cache entry it read,
        :func:`schedule.producers`) and ``cold_job`` (its CPU seconds there, the order of the next such run); ``cold``
        and ``warm`` the last run of that kind (kept when a later run is of the
        other kind or ``partial``).
    """
    path = Path(path)
    record = json.loads(path.read_text()) if path.exists() else {}
    entry = record.setdefault(mode, {"notebooks": {}})
    entry["date"] = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    entry["machine"] = machine_info()
    if hasattr(os, "getloadavg"):  # how busy the machine was: 1, 5 and 15 minute load averages at the end of the run
        entry["load"] = [round(x, 2) for x in os.getloadavg()]
    entry["jobs"] = jobs
    if wall is not None:
        entry["wall"] = round(wall, 1)
        if whole in ("cold", "warm") and all(r["ok"] for r in report):
            entry.setdefault("totals", {})[whole] = round(wall, 1)
    spans = {r["name"]: (r["start"], r["end"]) for r in report if "start" in r}
    beside = overlaps(spans) if jobs > 1 else {}
    # who computed what each lesson read (a run in which no lesson read another's entries, such as a clean run where
    # each lesson has an empty cache of its own, keeps the old lists)
    made_by = (producers(report) or None) if whole == "cold" else None
    known = entry["notebooks"]
    for r in report:
        known[r["name"]] = _notebook_entry(known.get(r["name"], {}), r, beside, made_by, whole)
    entry["notebooks"] = dict(sorted(entry["notebooks"].items()))
    path.write_text(json.dumps(dict(sorted(record.items())), indent=1) + "\n")
    return record


def _notebook_entry(old, r, beside, made_by, whole):
    """One notebook's new record entry from its ``old`` one and its report ``r`` (:func:`write_runtimes`)."""
    new = {"seconds": round(r["seconds"], 1), "ok": r["ok"]}
    if r.get("cpu") is not None:
        new["cpu"] = round(r["cpu"], 1)
    if beside.get(r["name"]):
        new["beside"] = beside[r["name"]]
    after = old.get("after") if made_by is None else made_by.get(r["name"])
    if after:
        new["after"] = after
    work = r.get("cpu") if r.get("cpu") is not None else r["seconds"]
    shared = whole == "cold" and r["ok"] and r.get("cache") != "cold"  # not a clean run's own empty cache
    job = round(work, 1) if shared else old.get("cold_job")
    if job is not None:
        new["cold_job"] = job
    if "cache" in r:
        new["cache"] = r["cache"]
        new.update({k: old[k] for k in ("cold", "warm") if k in old})
        if old.get("ok") and "cache" not in old:  # a record from before cold/warm: its runs were warm
            new.setdefault("warm", old["seconds"])
        if r["ok"] and r["cache"] in ("cold", "warm"):
            new[r["cache"]] = new["seconds"]
    return new


# "**Run time:** full 95 s, fast 20 s (measured by the main job)", and the older free forms such as
# "**Run time** on the 2-core machine: full ≈ 10 s, fast (`DEFOP_FAST=1`) ≈ 15 s" or "≈ 3 s (fast ≈ 8 s)"
_NUM = r"(?:≈\s*)?(?P<{0}>\d[\d,]*(?:\.\d+)?)\s*(?P<{0}_unit>s|min)\b"
RUN_TIME_RE = re.compile(
    r"\*\*Run time(?:\*\*)?[^:*\n]*:(?:\*\*)?\s*(?:full\s*)?"
    + _NUM.format("full")
    + r"(?:[^\n]*?|[^\n]*?\n[^\n]*?)"  # a remark, at most one line break
    + r"fast(?:[^≈\n]*?≈)?\s*"
    + _NUM.format("fast")
    + r"\)?(?: \(measured by the main job\))?",
)


# the canonical sentence (run_time_sentence), tried first so that a rewrite replaces all of it
_MEASURED = "(?:" + _NUM.format("{0}") + "|not measured)"
CANONICAL_RE = re.compile(
    r"\*\*Run time\*\* \(measured by the main job\): full "
    + _NUM.format("full")
    + " with the cache of a previous run, "
    + _MEASURED.format("full_cold")
    + " from an empty cache; fast "
    + _NUM.format("fast")
    + " with the cache, "
    + _MEASURED.format("fast_cold")
    + " from an empty cache"
)


def _seconds(value, unit):
    return float(value.replace(",", "")) * (60.0 if unit == "min" else 1.0)


def format_seconds(seconds):
    """``"502 s"`` below ten minutes, ``"12.4 min"`` above."""
    return f"{seconds:.0f} s" if seconds < 600 else f"{seconds / 60:.1f} min"


def _search(text):
    return CANONICAL_RE.search(text) or RUN_TIME_RE.search(text)


def parse_run_time(text, cold=False):
    """The stated (full, fast) run times in seconds from a "Run time" sentence, or None when there is none.

    ``cold=True``: the times "from an empty cache" of the canonical sentence instead (None for each one "not
    measured"; None for a sentence of another form, which states no such time).
    """
    m = _search(text)
    if m is None or (cold and m.re is not CANONICAL_RE):
        return None
    if cold:
        return tuple(None if m[k] is None else _seconds(m[k], m[k + "_unit"]) for k in ("full_cold", "fast_cold"))
    return _seconds(m["full"], m["full_unit"]), _seconds(m["fast"], m["fast_unit"])


def replace_run_time(text, sentence):
    """``text`` with its "Run time" sentence (the canonical one first, else an older form) replaced by ``sentence``."""
    pattern = CANONICAL_RE if CANONICAL_RE.search(text) else RUN_TIME_RE
    return pattern.sub(lambda _: sentence, text, count=1)


def run_time_sentence(full, fast, full_cold=None, fast_cold=None):
    """The canonical, machine-readable sentence (the cache-warm times first; a cold time None is "not measured").

    ``**Run time** (measured by the main job): full 95 s with the cache of a previous run, 4.2 min from an empty
    cache; fast 20 s with the cache, not measured from an empty cache``
    """

    def cold(seconds):
        return "not measured" if seconds is None else format_seconds(seconds)

    return (
        f"**Run time** (measured by the main job): full {format_seconds(full)} with the cache of a previous run, "
        f"{cold(full_cold)} from an empty cache; fast {format_seconds(fast)} with the cache, {cold(fast_cold)} "
        "from an empty cache"
    )


def stated_times(root=ROOT):
    """Every run time the documentation states.

    Returns
    -------
    stated : dict
        ``{name: (full, fast)}`` from each notebook's header, ``{"table:" + name: (full, fast)}`` from
        the table in ``notebooks/README.md`` and ``{"total": (full, fast)}`` from ``README.md``.
    """
    import nbformat

    stated = {}
    for path in notebooks(directory=Path(root) / "notebooks"):
        head = nbformat.read(path, as_version=4).cells[0].source
        stated[path.stem] = parse_run_time(head)
    for name, full, fast in _table_rows((Path(root) / "notebooks" / "README.md").read_text()):
        stated["table:" + name] = (full, fast)
    stated["total"] = parse_run_time((Path(root) / "README.md").read_text())
    stated["total:notebooks/README.md"] = parse_run_time((Path(root) / "notebooks" / "README.md").read_text())
    return stated


_ROW_RE = re.compile(r"^\| `(?P<name>\d\d_\w+)` \|(?P<mid>.*)\| (?P<full>[^|]*?) \| (?P<fast>[^|]*?) \|$", re.M)
_CELL_RE = re.compile(_NUM.format("v"))


def _table_rows(text):
    for m in _ROW_RE.finditer(text):
        a, b = _CELL_RE.search(m["full"]), _CELL_RE.search(m["fast"])
        if a and b:
            yield m["name"], _seconds(a["v"], a["v_unit"]), _seconds(b["v"], b["v_unit"])


def update_stated_times(path=RUNTIMES, root=ROOT):
    """Write the recorded run times into the headers, ``notebooks/README.md`` and ``README.md``.

    Notebooks without both a full and a fast record keep what they state. Run it after a full and a
    fast run of the main job (``python -m defop figures && python -m defop figures --fast``), or as
    ``python -m defop runtimes``.

    Returns
    -------
    changed : list of pathlib.Path
    """
    import nbformat

    full, full_cold = recorded_times(path, "full")
    fast, fast_cold = recorded_times(path, "fast")
    both = {k: (full[k], fast[k], full_cold.get(k), fast_cold.get(k)) for k in full.keys() & fast.keys()}
    changed = []
    for nb_path in notebooks(directory=Path(root) / "notebooks"):
        if nb_path.stem not in both:
            continue
        nb = nbformat.read(nb_path, as_version=4)
        sentence = run_time_sentence(*both[nb_path.stem])
        new = replace_run_time(nb.cells[0].source, sentence)
        if new != nb.cells[0].source:
            nb.cells[0].source = new
            nb_path.write_text(nbformat.writes(nb) + "\n")
            changed.append(nb_path)

    def row(m):
        if m["name"] not in both:
            return m[0]
        f, q = both[m["name"]][:2]
        return f"| `{m['name']}` |{m['mid']}| {format_seconds(f)} | {format_seconds(q)} |"

    changed += _rewrite(Path(root) / "notebooks" / "README.md", lambda t: _ROW_RE.sub(row, t))
    if full and fast and full.keys() == fast.keys():

        def total(times, cold):
            return sum(cold.values()) if cold.keys() == times.keys() else None

        runs = {mode: json.loads(Path(path).read_text()).get(mode, {}).get("totals", {}) for mode in ("full", "fast")}
        sentence = run_time_sentence(  # a whole run's wall time where measured (lessons side by side), else the sums
            runs["full"].get("warm", sum(full.values())),
            runs["fast"].get("warm", sum(fast.values())),
            runs["full"].get("cold", total(full, full_cold)),
            runs["fast"].get("cold", total(fast, fast_cold)),
        )
        for doc in ("README.md", "notebooks/README.md"):
            changed += _rewrite(Path(root) / doc, lambda t, s=sentence: replace_run_time(t, s))
    return sorted(set(changed))


def recorded_times(path=RUNTIMES, mode="full"):
    """The recorded seconds of one mode: ``(warm, cold)``, two dicts ``{name: seconds}``.

    ``warm`` ("with the cache of a previous run") holds every notebook with such a run (a record written before
    the cold/warm distinction counts as warm); ``cold`` ("from an empty cache") only those measured so.
    """
    notebooks_ = json.loads(Path(path).read_text()).get(mode, {}).get("notebooks", {})
    warm = {
        k: v["warm"] if "warm" in v else v["seconds"] for k, v in notebooks_.items() if "warm" in v or "cache" not in v
    }
    cold = {k: v["cold"] for k, v in notebooks_.items() if "cold" in v}
    return warm, cold


def _rewrite(path, edit):
    text = path.read_text()
    new = edit(text)
    if new == text:
        return []
    path.write_text(new)
    return [path]
