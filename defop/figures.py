"""The main job: regenerate every figure by executing the notebooks (``python -m defop figures``).

Each notebook in ``notebooks/`` is executed with nbclient, in its own directory, in full mode
(``DEFOP_FAST`` unset) unless ``fast=True``. Full runs store their outputs back into the
notebook, as the project's notebooks keep outputs from full runs. Figures are written by the
notebooks themselves into ``dop.config.figures_dir()``: the job sets ``DEFOP_FIGURES`` to ``figures/`` for full
runs only, so fast runs (and the test suite, which never sets it) write into a temporary directory.

What the job guarantees:

* **Progress.** One line per notebook as it starts and as it ends (name, seconds, ok/FAILED). The
  kernel runs with ``DEFOP_PROGRESS=text``, so training draws plain-text tqdm bars on its stderr;
  the client forwards them to this terminal and never stores them in the notebook.
* **No hang.** A per-cell timeout (:data:`CELL_TIMEOUT`, 1800 s by default) fails the notebook with a message naming the
  notebook, the cell index and the cell's first line. ipykernel 7 is excluded in pyproject.toml
  (under nbclient it intermittently never sends ``execute_reply``).
* **One failure is not the end.** A failed notebook is reported, the others still run, and
  :func:`regenerate` reports the failure so that ``python -m defop figures`` exits non-zero.
* **A timing record.** ``figures/runtimes.json`` holds, per mode (``full``/``fast``), each
  notebook's seconds, the date and the machine, and two figures per notebook: ``cold``, from an empty cache, and
  ``warm``, with the cache of a previous run. A clean run (``--clean``) runs every notebook with an empty cache of
  its own (its new entries are then moved into ``DEFOP_CACHE``), so its times are ``cold``; any other run whose
  notebook stored no new cache entry (everything it needed was cached) is ``warm``; a run that stored some is
  ``partial`` and sets neither. :func:`update_stated_times` writes those numbers into the "Run time" lines of the
  notebook headers, ``notebooks/README.md`` and ``README.md``.
* **No churn.** Stored notebooks are normalised by :func:`normalise` (nbstripout, keeping outputs):
  execution counts 1, 2, ... in order, no timing or widget-state metadata, no interpreter version, and widget outputs
  keep only their static picture and text line, so a regeneration that changes nothing gives no diff.
"""

from __future__ import annotations

import datetime
import fnmatch
import json
import os
import platform
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"
FIGURES = ROOT / "figures"
RUNTIMES = FIGURES / "runtimes.json"
#: per-cell timeout of the main job: the longest cell (07_octopus, training two 1,000-sample S-ARAP operators on the
#: octopus from an empty cache) took more than 600 s on this 2-core machine under load; a hang still fails in 30 min
CELL_TIMEOUT = 1800

# nbstripout's own defaults (its command line adds them) plus the interpreter version, which the kernel
# writes on every run and differs from machine to machine
STRIP_KEYS = (
    "metadata.signature",
    "metadata.widgets",
    "metadata.language_info.version",
    "cell.metadata.collapsed",
    "cell.metadata.ExecuteTime",
    "cell.metadata.execution",
    "cell.metadata.heading_collapsed",
    "cell.metadata.hidden",
    "cell.metadata.scrolled",
)
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"


class NotebookError(RuntimeError):
    """A notebook failed in the main job; the message names the notebook and the cell."""


def notebooks(only=None, directory=None):
    """The notebooks to run, in order.

    Parameters
    ----------
    only : str or list of str, optional
        Glob patterns on the file name (``"02_*"``); all when None.
    directory : path

    Returns
    -------
    paths : list of pathlib.Path
    """
    directory = NOTEBOOKS if directory is None else directory
    paths = sorted(Path(directory).glob("[0-9][0-9]_*.ipynb"))
    if only:
        pats = [only] if isinstance(only, str) else list(only)
        paths = [p for p in paths if any(fnmatch.fnmatch(p.name, pat) or pat in p.stem for pat in pats)]
        if not paths:
            raise ValueError(f"no notebook matches {pats}; known: {[p.name for p in notebooks(directory=directory)]}")
    return paths


# ---------------------------------------------------------------------------------------------- storing
def _static_outputs(outputs):
    """Widget outputs keep their static fallback (a picture and its text line); a widget with no picture
    (a progress bar frozen where it was, a raw ``VBox(children=…`` repr) is dropped: without a kernel it
    shows nothing true."""
    kept = []
    for out in outputs:
        data = out.get("data")
        if data and WIDGET_VIEW in data:
            data.pop(WIDGET_VIEW)
            if set(data) <= {"text/plain"}:
                continue
        kept.append(out)
    return kept


def normalise(nb):
    """Normalise a notebook for storing: the same content gives the same file on every machine.

    nbstripout (the Jupyter community's notebook cleaner, used by many projects as a git filter) with
    outputs and cell ids kept: it drops per-cell timing metadata, stored widget state and the interpreter
    version, and numbers the code cells 1, 2, ... Widget outputs keep only their static picture and text line.

    Parameters
    ----------
    nb : nbformat.NotebookNode
        Changed in place.

    Returns
    -------
    nb : nbformat.NotebookNode
    """
    from nbstripout import strip_output

    strip_output(nb, keep_output=True, keep_count=False, keep_id=True, extra_keys=list(STRIP_KEYS))
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    for count, cell in enumerate(code, start=1):
        cell.outputs = _static_outputs(cell.outputs)
        # numbered 1, 2, ... as a run-all numbers them (the same on every machine): nbval only compares the
        # outputs of cells with a count ("Unrun reference cell has outputs" otherwise)
        cell.execution_count = count
    return nb


def normalise_files(paths):
    """Normalise notebooks on disk (``python -m defop normalise``); returns the paths that changed."""
    import nbformat

    changed = []
    for path in map(Path, paths):
        before = path.read_text()
        nb = normalise(nbformat.reads(before, as_version=4))
        after = nbformat.writes(nb) + "\n"
        if after != before:
            path.write_text(after)
            changed.append(path)
    return changed


# ---------------------------------------------------------------------------------------------- running
def _client_class():
    from nbclient import NotebookClient

    class Client(NotebookClient):
        """nbclient that forwards progress bars (stderr text with carriage returns) to a terminal."""

        progress_stream = None
        current_cell = None

        def output(self, outs, msg, display_id, cell_index):
            content = msg.get("content", {})
            if msg["msg_type"] == "stream" and content.get("name") == "stderr" and "\r" in content.get("text", ""):
                if self.progress_stream is not None:
                    text = content["text"]
                    if not self.progress_stream.isatty():  # a log file: one line per update
                        text = "".join(s.strip() + "\n" for s in text.split("\r") if s.strip())
                    self.progress_stream.write(text)
                    self.progress_stream.flush()
                return None  # a progress bar is never stored in the notebook
            return super().output(outs, msg, display_id, cell_index)

    return Client


def _describe_cell(name, cell, index):
    first = next((ln for ln in cell.source.splitlines() if ln.strip() and not ln.startswith("# NBVAL")), "")
    return f"{name}, cell {index} ({first.strip()[:70]!r})"


def run_notebook(path, fast=False, store=None, timeout=CELL_TIMEOUT, kernel_name="python3", progress=sys.stderr):
    """Execute one notebook with nbclient.

    Parameters
    ----------
    path : path
        The ``.ipynb`` file.
    fast : bool
        Run with ``DEFOP_FAST=1``.
    store : bool, optional
        Write the executed notebook back (normalised); default: only for full runs.
    timeout : float
        Per-cell timeout in seconds.
    progress : file-like or None
        Where the kernel's progress bars go.

    Returns
    -------
    seconds : float

    Raises
    ------
    NotebookError
        A cell raised, timed out or the kernel died; the message names the notebook and the cell.
    """
    import nbformat

    path = Path(path)
    store = (not fast) if store is None else store
    nb = nbformat.read(path, as_version=4)
    env = {
        "DEFOP_FAST": "1" if fast else None,
        "DEFOP_FIGURES": None if fast else str(FIGURES),  # only full runs write the repository's figures/
        "DEFOP_PROGRESS": "text",
        "TQDM_MININTERVAL": None,
    }
    if progress is not None and not progress.isatty():
        env["TQDM_MININTERVAL"] = "15"  # a log file gets a line every 15 s, not every 0.1 s
    old = {k: os.environ.get(k) for k in env}
    _set_env(env)
    client = _client_class()(
        nb,
        timeout=timeout,
        kernel_name=kernel_name,
        resources={"metadata": {"path": str(path.parent)}},
        record_timing=False,  # widget state stays on: nbclient's Output-widget support needs it (normalise drops it)
    )
    client.progress_stream = progress
    client.on_cell_start = lambda cell, cell_index: setattr(client, "current_cell", (cell, cell_index))
    t0 = time.perf_counter()
    try:
        client.execute()
    except Exception as exc:
        where = _describe_cell(path.stem, *client.current_cell) if client.current_cell else path.stem
        kind = f"timed out after {timeout:.0f} s" if "Timeout" in type(exc).__name__ else "failed"
        detail = str(exc).strip().splitlines()
        raise NotebookError(f"{where} {kind}: {type(exc).__name__}: {detail[-1] if detail else ''}") from exc
    finally:
        _set_env(old)
    seconds = time.perf_counter() - t0
    if store:
        path.write_text(nbformat.writes(normalise(nb)) + "\n")
    return seconds


def _set_env(values):
    for key, value in values.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def _clean(log):
    for pattern in ("*.png", "table1.*"):
        for f in FIGURES.glob(pattern):
            f.unlink()
    from .config import cache_dir

    folder = cache_dir()
    if folder is not None:
        removed = 0
        for f in list(folder.glob("gt-*.npz")) + list(folder.glob("op-*.npz")) + list(folder.glob("traj-*")):
            f.unlink()
            removed += 1
        log(f"clean run: removed the figures and {removed} cached results from {folder}")


def _print(message):
    print(message, flush=True)


def _entries(folder):
    """{name: (inode, mtime)} of the cache entries in ``folder`` (hidden temporaries left out)."""
    if folder is None or not Path(folder).is_dir():
        return {}
    return {
        f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in Path(folder).iterdir() if not f.name.startswith(".")
    }


def _run_one(path, tag, log, cold=False, **kw):
    """Run one notebook between its two report lines; a failure is reported, not raised.

    ``cold``: run it with an empty cache of its own (a temporary ``DEFOP_CACHE``) whose entries are moved into the
    real cache afterwards. The report's ``cache`` is ``"cold"`` then, else ``"warm"`` when the notebook stored no
    new cache entry and ``"partial"`` when it stored some.
    """
    import shutil
    import tempfile

    from .config import cache_dir

    try:
        cache = cache_dir()
    except ValueError:  # a bad DEFOP_CACHE: the notebook fails with the message, and this run measures nothing
        cache = None
    before = {f: f.stat().st_mtime for f in FIGURES.glob("*")}
    own = Path(tempfile.mkdtemp(prefix="defop-cold-cache-")) if cold and cache is not None else None
    cached = _entries(cache)
    log(f"{tag} started ({'fast' if kw['fast'] else 'full'} mode{', empty cache' if cold else ''})")
    old = os.environ.get("DEFOP_CACHE")
    if own is not None:
        os.environ["DEFOP_CACHE"] = str(own)
    t0 = time.perf_counter()
    try:
        seconds, error = run_notebook(path, **kw), None
    except NotebookError as exc:
        seconds, error = time.perf_counter() - t0, str(exc)
    finally:
        if own is not None:
            _set_env({"DEFOP_CACHE": old})
            for f in own.iterdir():  # the notebook's results serve the next runs
                if not f.name.startswith("."):
                    shutil.move(str(f), str(cache / f.name))
            shutil.rmtree(own, ignore_errors=True)
    if cold or cache is None:
        state = "cold"  # no cache at all (DEFOP_CACHE=off) is an empty cache on every run
    else:
        state = "warm" if all(cached.get(k) == v for k, v in _entries(cache).items()) else "partial"
    written = sorted(f.name for f in FIGURES.glob("*") if before.get(f) != f.stat().st_mtime)
    status = "ok" if error is None else "FAILED"
    log(f"{tag} {status:6s} {seconds:7.1f} s ({state} cache)" + (f"  -> {', '.join(written)}" if written else ""))
    if error:
        log(f"    {error}")
    return dict(name=path.stem, seconds=seconds, ok=error is None, error=error, figures=written, cache=state)


def regenerate(
    only=None, fast=False, store=None, timeout=CELL_TIMEOUT, clean=False, log=_print, record=RUNTIMES, directory=None
):
    """Run the notebooks, one line per notebook as it starts and ends; a failure does not stop the others.

    Parameters
    ----------
    only : str or list of str, optional
        Notebook name patterns.
    fast : bool
        CI-sized sample counts (``DEFOP_FAST=1``).
    store : bool, optional
        Store outputs into the notebooks (default: full runs only).
    timeout : float
        Per-cell timeout in seconds.
    clean : bool
        A clean run: delete the figures and empty the cache of ground truths and operators
        (``DEFOP_CACHE``) first, and run every notebook with an empty cache of its own (its new entries are
        moved into ``DEFOP_CACHE`` after it), so everything is recomputed and the times are "from an empty cache".
    log : callable
    record : path or None
        The timing record to update (``figures/runtimes.json``); None writes none.
    directory : path, optional
        Where the notebooks are (default ``notebooks/``).

    Returns
    -------
    report : list of dict
        ``name``, ``seconds``, ``ok``, ``error`` (None or the message), ``figures`` written and ``cache``
        (``"cold"``, ``"warm"`` or ``"partial"``, see :func:`_run_one`).
    """
    from .view import render

    render.configure_headless()  # exported to the kernels through the environment
    FIGURES.mkdir(exist_ok=True)
    if clean:
        _clean(log)
    paths = notebooks(only, directory)
    mode = "fast" if fast else "full"
    report = []
    for i, path in enumerate(paths, 1):
        tag = f"[{i:2d}/{len(paths)}] {path.stem:<20s}"
        report.append(_run_one(path, tag, log, cold=clean, fast=fast, store=store, timeout=timeout))
    failed = [r["name"] for r in report if not r["ok"]]
    total = sum(r["seconds"] for r in report)
    log(
        f"{len(report)} notebooks in {total:.0f} s ({mode} mode); "
        + (f"FAILED: {', '.join(failed)}" if failed else "all ok")
    )
    if record is not None:
        write_runtimes(report, mode, record)
    return report


# ---------------------------------------------------------------------------------------------- timing record
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


def write_runtimes(report, mode, path=RUNTIMES):
    """Merge a run's seconds into the timing record (other modes and notebooks are kept).

    Parameters
    ----------
    report : list of dict
        From :func:`regenerate`.
    mode : {"full", "fast"}
    path : path

    Returns
    -------
    record : dict
        ``{mode: {"date", "machine", "load", "notebooks": {name: {"seconds", "ok", "cache", "cold", "warm"}}}}``:
        ``seconds``, ``ok`` and ``cache`` are the last run's; ``cold`` and ``warm`` the last run of that kind
        (kept when a later run is of the other kind or ``partial``).
    """
    path = Path(path)
    record = json.loads(path.read_text()) if path.exists() else {}
    entry = record.setdefault(mode, {"notebooks": {}})
    entry["date"] = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    entry["machine"] = machine_info()
    if hasattr(os, "getloadavg"):  # how busy the machine was: 1, 5 and 15 minute load averages at the end of the run
        entry["load"] = [round(x, 2) for x in os.getloadavg()]
    for r in report:
        old = entry["notebooks"].get(r["name"], {})
        new = {"seconds": round(r["seconds"], 1), "ok": r["ok"]}
        if "cache" in r:
            new["cache"] = r["cache"]
            new.update({k: old[k] for k in ("cold", "warm") if k in old})
            if old.get("ok") and "cache" not in old:  # a record from before cold/warm: its runs were warm
                new.setdefault("warm", old["seconds"])
            if r["ok"] and r["cache"] in ("cold", "warm"):
                new[r["cache"]] = new["seconds"]
        entry["notebooks"][r["name"]] = new
    entry["notebooks"] = dict(sorted(entry["notebooks"].items()))
    path.write_text(json.dumps(dict(sorted(record.items())), indent=1) + "\n")
    return record


# ---------------------------------------------------------------------------------------------- stated times
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


def _replace_run_time(text, sentence):
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
        new = _replace_run_time(nb.cells[0].source, sentence)
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

        sentence = run_time_sentence(
            sum(full.values()), sum(fast.values()), total(full, full_cold), total(fast, fast_cold)
        )
        for doc in ("README.md", "notebooks/README.md"):
            changed += _rewrite(Path(root) / doc, lambda t, s=sentence: _replace_run_time(t, s))
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
