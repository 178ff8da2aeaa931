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

import os
import sys
import time
from pathlib import Path

from . import paths, run_times, storing
from .paths import *  # noqa: F403 (the names in paths.__all__, and so on)
from .paths import FIGURES, NOTEBOOKS, RUNTIMES, notebooks
from .run_times import *  # noqa: F403
from .run_times import write_runtimes
from .storing import *  # noqa: F403
from .storing import normalise

__all__ = [
    "CELL_TIMEOUT",
    "NotebookError",
    "run_notebook",
    "regenerate",
    *paths.__all__,
    *run_times.__all__,
    *storing.__all__,
]

#: per-cell timeout of the main job: the longest cell (07_octopus, training two 1,000-sample S-ARAP operators on the
#: octopus from an empty cache) took more than 600 s on this 2-core machine under load; a hang still fails in 30 min
CELL_TIMEOUT = 1800


class NotebookError(RuntimeError):
    """A notebook failed in the main job; the message names the notebook and the cell."""


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
    env = _kernel_env(fast, progress)
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


def _kernel_env(fast, progress):
    """The environment the kernel runs in (None: unset): fast or full mode, where figures go, text progress bars."""
    env = {
        "DEFOP_FAST": "1" if fast else None,
        "DEFOP_FIGURES": None if fast else str(FIGURES),  # only full runs write the repository's figures/
        "DEFOP_PROGRESS": "text",
        "TQDM_MININTERVAL": None,
    }
    if progress is not None and not progress.isatty():
        env["TQDM_MININTERVAL"] = "15"  # a log file gets a line every 15 s, not every 0.1 s
    return env


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
    from ..config import cache_dir

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

    from ..config import cache_dir

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
    from ..view import render

    render.configure_headless()  # exported to the kernels through the environment
    FIGURES.mkdir(exist_ok=True)
    if clean:
        _clean(log)
    paths = notebooks(only, NOTEBOOKS if directory is None else directory)
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
