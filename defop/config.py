"""Run-time settings read from the environment.

``DEFOP_FAST=1``
    Fast mode for CI: notebooks shrink sample counts but keep their claims.
``DEFOP_CACHE``
    Directory of the on-disk cache of trained operators, sampled ground truths and trajectories
    (default: ``~/.cache/defop``; see :mod:`defop.training.cache`). ``DEFOP_CACHE=off`` disables it. A value
    naming a file or a directory that cannot be created or written raises ``ValueError`` when a
    computation starts, before any work is done.
``DEFOP_N_JOBS``
    Default number of parallel workers for sample solves (default: all cores).
``DEFOP_FIGURES``
    Where notebooks write their figures (see :func:`figures_dir`). Only the main job
    (``python -m defop figures``, full mode) sets it, to the repository's ``figures/``; everything else (fast mode,
    the test suite, a notebook opened by hand) writes into a temporary directory, so the shipped figures never
    change outside the main job.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

__all__ = ["fast_mode", "cache_dir", "figures_dir", "n_jobs", "pick"]

_OFF = ("off", "0", "none", "false", "no")


def fast_mode() -> bool:
    """True when ``DEFOP_FAST`` is set to a true value (1, true, yes, on)."""
    return os.environ.get("DEFOP_FAST", "").strip().lower() in ("1", "true", "yes", "on")


def pick(full, fast):
    """``fast`` in fast mode, else ``full``: ``m = dop.config.pick(400, 60)``."""
    return fast if fast_mode() else full


def cache_dir() -> Path | None:
    """The cache directory (created on demand and checked writable), or None when caching is off.

    Raises
    ------
    ValueError
        ``DEFOP_CACHE`` names a file, a directory that cannot be created, or one this process cannot
        write to (the message names ``DEFOP_CACHE`` and the path).
    """
    value = os.environ.get("DEFOP_CACHE", "").strip()
    if value.lower() in _OFF:
        return None
    source = f"DEFOP_CACHE={value!r}" if value else "the default DEFOP_CACHE"
    hint = "set DEFOP_CACHE to a writable directory, or DEFOP_CACHE=off to disable the cache"
    try:  # ~nosuchuser, or no home directory at all: pathlib raises RuntimeError
        path = Path(value).expanduser() if value else Path.home() / ".cache" / "defop"
    except (RuntimeError, KeyError, OSError) as exc:
        raise ValueError(f"{source}: cannot expand the home directory in it ({exc}); {hint}") from None
    if path.exists() and not path.is_dir():
        raise ValueError(f"{source}: {path} is not a directory; {hint}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        why = exc.strerror or exc
        raise ValueError(f"{source}: cannot create the cache directory {path} ({why}); {hint}") from exc
    try:  # a real write: os.access says yes to root on a read-only directory
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        why = exc.strerror or exc
        raise ValueError(f"{source}: cannot write to the cache directory {path} ({why}); {hint}") from exc
    return path


_TEMP_FIGURES: list[Path] = []  # this process's temporary figures directory, made on first use


def figures_dir() -> Path:
    """Where a notebook writes its figures: ``FIG = dop.config.figures_dir()``.

    ``DEFOP_FIGURES`` when set (the main job sets it to the repository's ``figures/`` for its full runs), else
    one temporary directory per process (removed when the process exits), so that fast runs and tests never write
    into the repository.

    Returns
    -------
    path : pathlib.Path
        An existing directory.

    Raises
    ------
    ValueError
        ``DEFOP_FIGURES`` names a file or a directory that cannot be created.
    """
    value = os.environ.get("DEFOP_FIGURES", "").strip()
    if not value:
        if not _TEMP_FIGURES:
            _TEMP_FIGURES.append(Path(tempfile.mkdtemp(prefix="defop-figures-")))
            atexit.register(shutil.rmtree, _TEMP_FIGURES[0], ignore_errors=True)
        return _TEMP_FIGURES[0]
    path = Path(value).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"DEFOP_FIGURES={value!r}: {path} is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"DEFOP_FIGURES={value!r}: cannot create {path} ({exc.strerror or exc})") from exc
    return path


def n_jobs() -> int:
    """Default worker count for joblib: ``DEFOP_N_JOBS`` or every core (-1).

    Raises
    ------
    ValueError
        ``DEFOP_N_JOBS`` is not a non-zero integer.
    """
    value = os.environ.get("DEFOP_N_JOBS", "").strip()
    if not value:
        return -1
    try:
        jobs = int(value)
    except ValueError:
        jobs = 0
    if jobs == 0:
        raise ValueError(f"DEFOP_N_JOBS={value!r} must be a non-zero integer (-1: every core)")
    return jobs
