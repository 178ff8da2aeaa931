"""The one batch-solve layer: many independent solves of problem (6), in parallel, with progress and a cache.

Training (:func:`defop.training.bootstrap.solve_samples`) and the ground-truth trajectories
(:func:`defop.analysis.trajectories.ground_truth_trajectories`) both run through :func:`parallel_map` and
:func:`load_or_compute`, so the split into chunks, the joblib backend (a Dask cluster included), the progress bars
and the cache policy are written once.
"""

from __future__ import annotations

import os

import numpy as np

from .. import config
from .. import options as opt

__all__ = ["load_or_compute", "parallel_map", "progress"]


def progress(total, desc, enabled):
    """A progress bar over ``total`` solves, or None.

    Parameters
    ----------
    total : int
    desc : str
    enabled : bool or callable
        False: no bar. A callable: ``enabled(total=total, desc=desc)`` makes the bar, any object with
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
    return tqdm(total=total, desc=desc, leave=False)


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
    from joblib import Parallel, delayed, effective_n_jobs

    items = list(items)
    m = len(items)
    n_jobs = opt.n_jobs(config.n_jobs() if n_jobs is None else n_jobs)  # more than the cores: capped, warned
    bar = progress(m, desc, show)
    results = []
    try:
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
    finally:
        if bar:
            bar.close()


def load_or_compute(store, kind, key, expect, compute):
    """The cache policy: the arrays of entry ``kind``/``key`` if a valid one is stored, else ``compute()``, stored.

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
    if store is not None:
        hit = store.load(kind, key, expect)
        if hit is not None:
            return hit[0]
    arrays = compute()
    if store is not None:
        store.store(kind, key, arrays)
    return arrays
