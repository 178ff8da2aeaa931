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
import time
from pathlib import Path

from .. import options as opt
from . import execute, paths, run_times, schedule, storing
from .execute import CELL_TIMEOUT, NotebookError, run_notebook
from .paths import *  # noqa: F403 (the names in paths.__all__, and so on)
from .paths import FIGURES, NOTEBOOKS, RUNTIMES, notebooks
from .run_times import *  # noqa: F403
from .run_times import format_seconds, write_runtimes
from .storing import *  # noqa: F403

__all__ = [
    *execute.__all__,
    "regenerate",
    *paths.__all__,
    *run_times.__all__,
    *storing.__all__,
]


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


def _lesson_env(work, cold, cache, fast, inner):
    """The kernel's environment of one lesson and where its cache entries and figures go first: ``(env, own cache or
    None, own figures or None)``. The journal of the entries it stores is ``work/journal``."""
    import tempfile

    env = {"DEFOP_CACHE_LOG": str(work / "journal")}
    if inner is not None and "DEFOP_N_JOBS" not in os.environ:  # side by side: the lesson's solves in its kernel
        env.update(
            {k: str(inner) for k in ("DEFOP_N_JOBS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
        )
    own = None
    if cold and cache is not None:  # an empty cache of its own, on the cache's file system (renamed into it after)
        own = Path(tempfile.mkdtemp(prefix=".cold-", dir=cache))
        env["DEFOP_CACHE"] = str(own)
    figures = None
    if not fast:  # its figures apart, renamed into figures/ after: each lesson's list is its own
        figures = Path(tempfile.mkdtemp(prefix=".lesson-", dir=FIGURES))
        env["DEFOP_FIGURES"] = str(figures)
    return env, own, figures


def _move_into(source, target):
    """Rename every visible file of the directory ``source`` into ``target`` (same file system), remove ``source``;
    the names moved, sorted."""
    import shutil

    if not source.is_dir():  # removed meanwhile (cache --prune of a folder left by a killed run)
        return []
    names = sorted(f.name for f in source.iterdir() if not f.name.startswith("."))
    for name in names:
        os.replace(source / name, target / name)
    shutil.rmtree(source, ignore_errors=True)
    return names


def _lesson(path, cold=False, inner=None, prefix=None, **kw):
    """Run one notebook, here or in a worker process of :func:`regenerate`; a failure is reported, not raised.

    ``cold``: with an empty cache of its own whose entries then join the real cache. ``inner``: the solver workers
    of its kernel (``DEFOP_N_JOBS``, and as many BLAS threads), None for the default. ``prefix``: of its progress lines.

    Returns
    -------
    report : dict
        ``name``, ``seconds`` (wall), ``cpu`` (of its kernel and workers, None when unknown), ``ok``, ``error``,
        ``figures`` written, ``cache`` (``"cold"``; ``"warm"`` when it stored no cache entry; ``"partial"``),
        ``computed`` (the cache entries it stored) and ``start``/``end`` (``time.time()``).
    """
    import shutil
    import tempfile

    from ..config import cache_dir
    from ..training import cache_files

    try:
        cache = cache_dir()
    except ValueError:  # a bad DEFOP_CACHE: the notebook fails with the message, and this run measures nothing
        cache = None
    work = Path(tempfile.mkdtemp(prefix="defop-lesson-"))
    env, own, figures = _lesson_env(work, cold, cache, kw["fast"], inner)
    before = _entries(cache) if inner is None else None  # alone: any new file in the cache counts, not only stores
    measured, start, t0 = {}, time.time(), time.perf_counter()
    try:
        seconds, error = run_notebook(path, prefix=prefix, env=env, measured=measured, **kw), None
    except NotebookError as exc:
        seconds, error = time.perf_counter() - t0, str(exc)
    finally:
        if own is not None:
            _move_into(own, cache)  # the notebook's results serve the next runs
        written = [] if figures is None else _move_into(figures, FIGURES)
        journal = work / "journal"
        computed, read = cache_files.journal_entries(journal.read_text() if journal.exists() else "")
        shutil.rmtree(work, ignore_errors=True)
    new = computed or (before is not None and any(before.get(k) != v for k, v in _entries(cache).items()))
    state = "cold" if cold or cache is None else ("partial" if new else "warm")  # no cache: an empty one every run
    return dict(
        name=path.stem, seconds=seconds, cpu=measured.get("cpu"), ok=error is None, error=error, figures=written,
        cache=state, computed=computed, read=read, start=start, end=time.time(),
    )  # fmt: skip


def _end_line(tag, r, eta=None):
    status = "ok" if r["ok"] else "FAILED"
    cpu = "" if r["cpu"] is None else f", {r['cpu']:.0f} CPU s"
    line = f"{tag} {status:6s} {r['seconds']:7.1f} s{cpu} ({r['cache']} cache)"
    line += "" if eta is None else f"; about {format_seconds(eta)} to go"
    line += f"  -> {', '.join(r['figures'])}" if r["figures"] else ""
    return line + (f"\n    {r['error']}" if r["error"] else "")


def _started(tag, fast, cold):
    return f"{tag} started ({'fast' if fast else 'full'} mode{', empty cache' if cold else ''})"


def _run_one(path, tag, log, cold=False, **kw):
    """Run one notebook in this process between its two report lines (:func:`_lesson`)."""
    log(_started(tag, kw["fast"], cold))
    report = _lesson(path, cold=cold, **kw)
    log(_end_line(tag, report))
    return report


def _side_by_side(paths, tags, jobs, expected, log, after=None, **kw):
    """Run the notebooks ``paths`` (in this order) on ``jobs`` worker processes, each starting on the first to free
    once the lessons it waits on (``after``, :func:`schedule.next_ready`) have ended; their report lines as they start
    and end, with the time to go (:func:`schedule.eta`)."""
    after = {} if after is None else after
    import concurrent.futures as cf
    import multiprocessing

    queue, running, report = list(paths), {}, []
    inner = schedule.inner_jobs(jobs)
    with cf.ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        while queue or running:
            while queue and len(running) < jobs:
                names = [p.stem for p in queue]
                i = schedule.next_ready(names, {*names, *(p.stem for p, _ in running.values())}, after, running)
                if i is None:  # every queued lesson waits on one that runs
                    break
                path = queue.pop(i)
                log(_started(tags[path], kw["fast"], kw["cold"]))
                job = pool.submit(_lesson, path, inner=inner, prefix=path.stem, **kw)
                running[job] = (path, time.perf_counter())
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            for job in done:
                path, t0 = running.pop(job)
                try:
                    r = job.result()
                except Exception as exc:  # the worker died (killed, out of memory): this lesson failed
                    error = f"{path.stem}: the worker running it failed: {type(exc).__name__}: {exc}"
                    now, wall = time.time(), time.perf_counter() - t0
                    r = dict(name=path.stem, seconds=wall, cpu=None, ok=False, error=error, figures=[], cache="partial",
                             computed=[], read=[], start=now - wall, end=now)  # fmt: skip
                left = schedule.eta(
                    [expected[p.stem] for p in queue],
                    [(expected[p.stem], time.perf_counter() - t) for p, t in running.values()],
                    jobs,
                )
                log(_end_line(tags[path], r, eta=left))
                report.append(r)
    return report


def regenerate(
    only=None,
    fast=False,
    store=None,
    timeout=CELL_TIMEOUT,
    clean=False,
    log=_print,
    record=RUNTIMES,
    directory=None,
    jobs=1,
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
    jobs : int
        Notebooks side by side (:mod:`defop.figures.schedule`: longest first by the record, each on the first
        worker to free, each kernel's solves in the kernel); 1: one after another in this process, in name order.
        The workers are spawned: a script that calls this with ``jobs > 1`` does so under
        ``if __name__ == "__main__":``.

    Returns
    -------
    report : list of dict
        In name order, as :func:`_lesson` reports.
    """
    from ..view import render

    jobs = opt.integer("jobs", jobs, minimum=1)
    render.configure_headless()  # exported to the kernels through the environment
    FIGURES.mkdir(exist_ok=True)
    if clean:
        _clean(log)
    paths = notebooks(only, NOTEBOOKS if directory is None else directory)
    mode = "fast" if fast else "full"
    cold = clean or _empty_cache()  # a fresh clone: the times recorded from an empty cache
    expected = schedule.expected_seconds([p.stem for p in paths], RUNTIMES if record is None else record, mode, cold)
    tags = {p: f"[{i:2d}/{len(paths)}] {p.stem:<20s}" for i, p in enumerate(paths, 1)}
    beside, alone = _plan(paths, expected, jobs, mode, log)
    t0 = time.perf_counter()
    kw = dict(cold=clean, fast=fast, store=store, timeout=timeout)
    if jobs == 1:
        report = [_run_one(path, tags[path], log, **kw) for path in paths]
    else:
        after = schedule.recorded_after([p.stem for p in beside], RUNTIMES if record is None else record, mode)
        report = _side_by_side(beside, tags, jobs, expected, log, after=after if cold and not clean else None, **kw)
        report += [_run_one(path, tags[path], log, **kw) for path in alone]  # their measured times: nothing beside
        report.sort(key=lambda r: r["name"])
    _summary(report, mode, jobs, time.perf_counter() - t0, log)
    if record is not None:
        whole = _whole(only, cold, report)
        write_runtimes(report, mode, record, jobs=jobs, wall=time.perf_counter() - t0, whole=whole)
    return report


def _plan(paths, expected, jobs, mode, log):
    """The notebooks to run side by side (longest first) and those to run alone after them
    (:func:`schedule.plan`), and the line announcing the expected wall time."""
    side = f"{jobs} side by side, longest first" if jobs > 1 else "one at a time"
    by_name = {p.stem: p for p in paths}
    beside, alone = ([by_name[n] for n in names] for names in schedule.plan(list(by_name), expected, jobs))
    total = schedule.makespan([expected[p.stem] for p in beside], jobs) + sum(expected[p.stem] for p in alone)
    log(f"{len(paths)} notebooks ({mode} mode, {side}): about {format_seconds(total)} by the recorded times")
    return beside, alone


def _whole(only, cold, report):
    """``"cold"`` for a run of every notebook from an empty cache, ``"warm"`` for one that only read the cache,
    else None (:func:`write_runtimes`)."""
    if only:
        return None
    return "cold" if cold else ("warm" if all(r["cache"] == "warm" for r in report) else None)


def _empty_cache():
    """True when the cache holds no trained operator (or is off, or unusable)."""
    from ..config import cache_dir

    try:
        folder = cache_dir()
    except ValueError:
        return True
    return folder is None or next(folder.glob("op-*.npz"), None) is None


def _summary(report, mode, jobs, wall, log):
    failed = [r["name"] for r in report if not r["ok"]]
    cpu = [r["cpu"] for r in report if r["cpu"] is not None]
    log(
        f"{len(report)} notebooks in {format_seconds(wall)} wall ({mode} mode"
        + (
            f", {jobs} side by side; their own times sum to {sum(r['seconds'] for r in report):.0f} s"
            if jobs > 1
            else ""
        )
        + (f"; {sum(cpu):.0f} CPU s" if cpu else "")
        + "); "
        + (f"FAILED: {', '.join(failed)}" if failed else "all ok")
    )
