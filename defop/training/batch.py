"""The parallel layer under the sample engine: chunks over joblib workers, progress bars, checkpoints, the cache policy.

The sample engine (:mod:`defop.training.solves`, the only code that solves problem (6) for many samples) runs
through :func:`parallel_map` and :func:`map_checkpointed`, and its callers cache whole results through
:func:`load_or_compute`, so the split into chunks, the joblib backend (a Dask cluster included), the progress bars
and the cache policy are written once; :func:`map_checkpointed` adds the checkpoints that let an interrupted run
resume (:class:`Checkpoints`).
"""

from __future__ import annotations

import contextlib
import os
import warnings

import numpy as np

from .. import config
from .. import options as opt
from ..variational import energies as en
from .cache import CacheWarning

__all__ = ["CHUNK", "Checkpoints", "Stages", "hold", "load_or_compute", "map_checkpointed", "parallel_map", "progress"]

#: Items per checkpoint of :func:`map_checkpointed`: fixed, so the chunks (and their cache keys) do not depend on the
#: worker count and a training killed with one ``n_jobs`` resumes with another.
CHUNK = 25


def progress(total, desc, enabled):
    """A progress bar over ``total`` solves, or None.

    Parameters
    ----------
    total : int
    desc : str
    enabled : bool or callable
        False: no bar. The tqdm bars count solves and show the elapsed time, the remaining time (the ETA) and the
        rate (``12/500 [00:31<20:45, 2.6 s/solve]``). A callable: ``enabled(total=total, desc=desc)`` makes the
        bar, any object with
        ``update(n)`` and ``close()`` (the playground passes its widget bar). True: ``tqdm.auto`` (a
        widget in a live notebook), except with ``DEFOP_PROGRESS=text``, set by the main job: a plain
        text bar on stderr, which the job forwards to the terminal instead of storing a widget frozen
        at 0 % in the notebook.

    Returns
    -------
    bar : object or None
    """
    if not enabled:
        return None
    if callable(enabled):
        return enabled(total=total, desc=desc)
    if os.environ.get("DEFOP_PROGRESS", "").strip().lower() == "text":
        from tqdm.std import tqdm
    else:
        from tqdm.auto import tqdm
    return tqdm(total=total, desc=desc, leave=False, unit="solve", smoothing=0.1)


class Stages:
    """One progress display over the stages of a computation: a single bar (:func:`progress`) whose total is the
    solves of every stage and whose ETA is over all of them, its description naming the stage that runs.

    Pass it where a stage takes ``progress`` (:func:`defop.training.solves.solve`'s, :func:`parallel_map`'s
    ``show``): called as ``stages(total=k, desc=...)`` it names the stage and returns a view of the one bar that
    counts the stage's k solves and whose ``close()`` leaves the bar open. :meth:`close` closes it.

    Parameters
    ----------
    total : int
        Solves of every stage together.
    enabled : bool or callable
        As :func:`progress` (a callable makes the one bar, once).
    desc : str
        The computation's name, before each stage's.
    """

    def __init__(self, total, enabled, desc="training"):
        self.desc = desc
        self.bar = progress(int(total), desc, enabled)

    def __bool__(self):
        return self.bar is not None

    def __call__(self, total=0, desc=""):
        if self.bar is not None and hasattr(self.bar, "set_description"):
            self.bar.set_description(f"{self.desc}: {desc}" if desc else self.desc)
        return _StageView(self.bar)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class _StageView:
    """A stage's view of :class:`Stages`'s bar: counts solves on it; closing the stage leaves the bar open."""

    def __init__(self, bar):
        self.bar = bar

    def __bool__(self):
        return self.bar is not None

    def update(self, n=1):
        if self.bar is not None:
            self.bar.update(n)

    def close(self):
        pass


def parallel_map(fn, items, n_jobs=None, show=False, desc="solving"):
    """``fn`` over contiguous chunks of ``items`` with joblib, results in the order of ``items``.

    The chunks (about four per worker) depend only on ``len(items)`` and the worker count, never on which
    worker finishes first, and each item's result depends only on the item: the same inputs give the same
    answers for any ``n_jobs`` and any joblib backend.

    Parameters
    ----------
    fn : callable
        ``fn(chunk) -> list`` with one result per item of the chunk (a list); picklable for process workers.
    items : sequence
    n_jobs : int, optional
        Workers (default :func:`defop.config.n_jobs`: every core); 1, or at most two items, runs in this process.
    show : bool or callable
        A progress bar over the items (:func:`progress`).
    desc : str

    Returns
    -------
    results : list
    """
    items = list(items)
    n_jobs = opt.n_jobs(config.n_jobs() if n_jobs is None else n_jobs)  # checked before a bar is shown
    bar = progress(len(items), desc, show)
    try:
        return _run(fn, items, n_jobs, bar)
    finally:
        if bar:
            bar.close()


def _run(fn, items, n_jobs, bar):
    """:func:`parallel_map`'s work, advancing ``bar`` (or None) as chunks finish."""
    from joblib import Parallel, delayed, effective_n_jobs

    m = len(items)
    n_jobs = opt.n_jobs(config.n_jobs() if n_jobs is None else n_jobs)  # more than the cores: capped, warned
    results = []
    if n_jobs == 1 or m <= 2:
        for i in range(m):
            results += fn(items[i : i + 1])
            if bar:
                bar.update(1)
        return results
    n_chunks = min(m, 4 * max(1, effective_n_jobs(n_jobs)))
    bounds = np.linspace(0, m, n_chunks + 1).astype(int)
    chunks = [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    gen = Parallel(n_jobs=n_jobs, return_as="generator")(delayed(fn)(items[a:b]) for a, b in chunks)
    for (a, b), res in zip(chunks, gen):
        results += res
        if bar:
            bar.update(b - a)
    return results


class Checkpoints:
    """The cache entries of one computation's finished chunks (:func:`map_checkpointed`), to resume it after an
    interruption and to remove once its whole result is cached.

    Parameters
    ----------
    store : defop.training.cache.Cache
    """

    KIND = "chunk"

    def __init__(self, store):
        self.store = store
        self.keys = []

    def load_or_compute(self, key, expect, compute):
        """:func:`load_or_compute` of entry ``chunk``/``key``, remembered for :meth:`discard`.

        A checkpoint that cannot be written is skipped silently: the caller's whole result, stored next, warns.
        """
        self.keys.append(key)
        hit = self.store.load(self.KIND, key, expect)
        if hit is not None:
            return hit[0]
        arrays = compute()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CacheWarning)
            self.store.store(self.KIND, key, arrays)
        return arrays

    def discard(self):
        """Remove every chunk entry used so far (the caller has cached the whole result)."""
        for key in self.keys:
            self.store.remove(self.KIND, key)
        self.keys = []


def map_checkpointed(fn, items, n_jobs, show, desc, chunk):
    """:func:`parallel_map` over fixed chunks of :data:`CHUNK` items, each cached as soon as it is finished.

    Parameters
    ----------
    fn, items, n_jobs, show, desc
        As in :func:`parallel_map`.
    chunk : callable or None
        ``chunk(a, b, compute) -> list``: the results of ``items[a:b]``, loaded from a checkpoint or ``compute()``
        and stored (e.g. through :meth:`Checkpoints.load_or_compute`); None: no checkpoints. Nor are there for
        at most :data:`CHUNK` items: the caller's own cache entry follows at once.

    Returns
    -------
    results : list
        As :func:`parallel_map`'s: each item's result depends only on the item, so a resumed run returns what an
        uninterrupted one does.
    """
    items = list(items)
    if chunk is None or len(items) <= CHUNK:
        return parallel_map(fn, items, n_jobs, show, desc)
    bar = progress(len(items), desc, show)
    results = []
    try:
        for a in range(0, len(items), CHUNK):
            b = min(a + CHUNK, len(items))
            solved = []

            def compute(a=a, b=b, solved=solved):
                solved.append(b - a)
                return _run(fn, items[a:b], n_jobs, bar)

            res = chunk(a, b, compute)
            if bar and not solved:  # loaded: the bar counts it at once, the ETA from the solves left
                bar.update(b - a)
            results += list(res)
        return results
    finally:
        if bar:
            bar.close()


def hold(store, kind, key):
    """A context holding entry ``kind``/``key``'s lock (:meth:`defop.training.cache.Cache.lock`); none without a
    cache (``store`` None)."""
    return contextlib.nullcontext() if store is None else store.lock(kind, key)


def load_or_compute(store, kind, key, expect, compute):
    """The cache policy: the arrays of entry ``kind``/``key`` if a valid one is stored, else ``compute()``, stored.

    A process that misses the entry while another computes it (:meth:`defop.training.cache.Cache.lock`) waits and
    reads what the other stored, instead of computing it again.

    Parameters
    ----------
    store : defop.training.cache.Cache or None
        None: no cache (``DEFOP_CACHE=off`` or ``cache=False``).
    kind, key : str
    expect : dict
        ``{name: (shape, dtype kind)}`` a valid entry must match (see :meth:`Cache.load`).
    compute : callable
        ``compute() -> dict`` of numpy arrays.

    Returns
    -------
    arrays : dict
    """
    if store is None:
        return compute()
    hit = store.load(kind, key, expect)
    if hit is None:
        with hold(store, kind, key):  # another process computing this entry: wait for it, then read it
            hit = store.load(kind, key, expect)
            if hit is None:
                arrays = compute()
                store.store(kind, key, arrays)
                return arrays
    return hit[0]


def warm_starts(op, samples, mesh, energy):
    """The warm-start rule of every training policy: an operator's predictions at ``samples``, None where flipped.

    Parameters
    ----------
    op : callable
        A fitted operator (``op(samples)`` -> (k, n, d)); its ExtrapolationWarning is silenced, the solver corrects
        a start that extrapolates.
    samples : (k, handles, d) array
    mesh : Mesh
    energy : str
        For a barrier energy a prediction that flips an element is no start (None).

    Returns
    -------
    list of (n, d) arrays or None
    """
    from ..operator.defop import ExtrapolationWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        predictions = op(samples)
    return [None if en.is_barrier(energy) and np.any(mesh.flipped(X)) else X for X in predictions]
