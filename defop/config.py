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
``DEFOP_MKL_THREADS``, ``DEFOP_BACKEND``
    MKL's threads and the factorisation back end (:mod:`defop.variational.problem`).

Every integer setting is read by :func:`integer_setting`: ASCII decimal digits only (``'²'`` and ``'٣'`` pass
``str.isdigit`` but are refused), the message naming the variable.
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

__all__ = ["fast_mode", "cache_dir", "figures_dir", "n_jobs", "pick", "integer_setting", "parse_integer"]

_OFF = ("off", "0", "none", "false", "no")
_ASCII_SPACE = " \t\n\r\f\v"
#: the largest integer setting: a C int (MKL's thread count goes through ctypes.c_int, which wraps silently)
MAX_INTEGER_SETTING = 2**31 - 1


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


def parse_integer(name, raw, default, minimum=1, maximum=MAX_INTEGER_SETTING, signed=False, nonzero=False, rule=None):
    """The integer an environment setting's text ``raw`` names, checked before ``int()`` sees it.

    Only ASCII decimal digits count (with one leading ``-`` when ``signed``), after stripping ASCII white space:
    ``str.isdigit`` and ``int`` also accept ``'²'``, ``'٣'``, ``'+3'`` and ``'1_000'``, and ``int`` fails on
    some of them without naming the variable. An empty value gives ``default``.

    Parameters
    ----------
    name : str
        The variable, named in the message.
    raw : str or None
    default : int
    minimum, maximum : int or None
        Inclusive bounds (the maximum also keeps ``int()`` off a 5,000-digit string).
    signed : bool
        Accept a leading minus sign.
    nonzero : bool
        Refuse 0.
    rule : str, optional
        What the value must be, for the message (default: ``"a whole number >= {minimum}"``).

    Returns
    -------
    int

    Raises
    ------
    ValueError
        ``"{name} must be {rule}, got {raw!r}"``.
    """
    value = (raw or "").strip(_ASCII_SPACE)
    if not value:
        return default
    digits = value[1:] if signed and value.startswith("-") else value
    number = None
    if digits and len(digits) <= len(str(MAX_INTEGER_SETTING)) and all("0" <= ch <= "9" for ch in digits):
        number = int(value)
    in_range = (
        number is not None
        and (minimum is None or number >= minimum)
        and (maximum is None or number <= maximum)
        and not (nonzero and number == 0)
    )
    if not in_range:
        if rule is None:
            bounds = [f">= {minimum}" if minimum is not None else "", f"<= {maximum}" if maximum is not None else ""]
            rule = "a whole number " + " and ".join(b for b in bounds if b)
        raise ValueError(f"{name} must be {rule}, got {raw!r:.80}")
    return number


def integer_setting(name, default, **kw):
    """The integer setting ``name`` from the environment (:func:`parse_integer`'s rules), or ``default``."""
    return parse_integer(name, os.environ.get(name), default, **kw)


def n_jobs() -> int:
    """Default worker count for joblib: ``DEFOP_N_JOBS`` or every core (-1).

    Raises
    ------
    ValueError
        ``DEFOP_N_JOBS`` is not a non-zero integer (ASCII digits, an optional minus sign).
    """
    rule = f"a non-zero integer from -{MAX_INTEGER_SETTING} to {MAX_INTEGER_SETTING} (-1: every core)"
    return integer_setting("DEFOP_N_JOBS", -1, minimum=-MAX_INTEGER_SETTING, signed=True, nonzero=True, rule=rule)
