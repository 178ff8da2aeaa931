"""Validation of user options, one message style: the option's name, what it must be, what was given."""

from __future__ import annotations

import contextlib
import numbers
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from . import config


def integer(name, value, minimum=None, maximum=None):
    """``value`` as an int, checked to be an integer (an integral float is accepted) within bounds.

    Raises
    ------
    ValueError
        ``"{name} must be an integer >= {minimum}, got {value!r}"`` (bools, fractions, NaN, strings, floats
        beyond 2**53).
    """
    ok = isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if not ok and isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        # an integral float, exactly: 1e300 is "integral" but no count or seed (it overflowed numpy, igl)
        ok = bool(np.isfinite(value)) and float(value).is_integer() and abs(float(value)) <= 2**53
    if ok:
        value_int = int(value)
        if (minimum is None or value_int >= minimum) and (maximum is None or value_int <= maximum):
            return value_int
    bounds = [f">= {minimum}" if minimum is not None else "", f"<= {maximum}" if maximum is not None else ""]
    what = " and ".join(b for b in bounds if b)
    raise ValueError(f"{name} must be an integer{' ' + what if what else ''}, got {value!r}")


def choice(name, value, options):
    """``value`` checked to be one of ``options`` (strings); the message lists them."""
    if not isinstance(value, str) or value not in options:
        raise ValueError(f"unknown {name} {value!r}; known: {', '.join(options)}")
    return value


def cpu_count():
    """The cores this process may use (its CPU affinity where the OS tells it, else ``os.cpu_count()``)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def n_jobs(value):
    """A joblib worker count: None (the ``DEFOP_N_JOBS`` default, checked here) or a non-zero integer.

    More workers than :func:`cpu_count` are capped at it with a warning: ``train(n_jobs=1000)`` started a
    thousand processes on two cores.
    """
    if value is None:
        config.n_jobs()  # a bad DEFOP_N_JOBS fails now, not after the first stage of work
        return None
    jobs = integer("n_jobs", value)
    if jobs == 0:
        raise ValueError("n_jobs must be a non-zero integer (-1: every core, 1: this process), got 0")
    cores = cpu_count()
    if jobs > cores:
        warnings.warn(
            f"n_jobs={jobs} is more than the {cores} cores of this machine; using {cores}",
            RuntimeWarning,
            stacklevel=user_stacklevel(),
        )
        jobs = cores
    return jobs


def seed(value, name="seed"):
    """A sampling seed: a non-negative integer (``numpy.random.default_rng(seed)``).

    Raises
    ------
    ValueError
        ``"{name} must be an integer >= 0, got ..."``: a string, float, None or negative seed (numpy's own
        ``SeedSequence`` TypeError did not name the argument).
    """
    return integer(name, value, minimum=0)


def rng(value, name="rng"):
    """A ``numpy.random.Generator``: ``value`` itself, or one seeded by it (a BitGenerator or SeedSequence too).

    Raises
    ------
    ValueError
        ``value`` is none of these nor a seed :func:`seed` accepts (the message names ``name``).
    """
    if isinstance(value, np.random.Generator):
        return value
    if isinstance(value, (np.random.BitGenerator, np.random.SeedSequence)):
        return np.random.default_rng(value)
    try:
        return np.random.default_rng(seed(value, name))
    except ValueError:
        raise ValueError(
            f"{name} must be a numpy.random.Generator or a seed (an integer >= 0), got "
            f"{type(value).__name__} {value!r:.80}"
        ) from None


def real_array(name, value, cast=True):
    """``value`` as a float numpy array, refusing what a float cast would silently mangle.

    ``cast=False`` returns integer and float arrays as they are (checked, not copied).

    Raises
    ------
    ValueError
        ``"{name} must be an array of real numbers, got ..."`` for complex (the imaginary part would be dropped),
        boolean, string or object input, and for ragged nested lists.
    """
    try:
        arr = np.asarray(value)
    except ValueError as exc:  # ragged nested sequences
        raise ValueError(f"{name} must be an array of real numbers, got a ragged sequence ({exc})") from None
    if arr.dtype.kind not in "iuf":
        what = {"c": "complex numbers", "b": "booleans", "U": "strings", "S": "bytes", "O": "Python objects"}
        raise ValueError(
            f"{name} must be an array of real numbers, got {what.get(arr.dtype.kind, f'dtype {arr.dtype}')}"
        )
    return arr.astype(float, copy=False) if cast else arr


def positive(name, value, maximum=None):
    """``value`` as a float, checked to be a finite real number > 0 (and <= ``maximum`` when given).

    Raises
    ------
    ValueError
        ``"{name} must be a positive number, got {value!r}"`` (bools, strings, NaN, inf, 0 and below), with
        ``<= {maximum}`` in the message when a maximum is given.
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if not ok or not np.isfinite(value) or value <= 0 or (maximum is not None and value > maximum):
        bound = f" <= {maximum}" if maximum is not None else ""
        raise ValueError(f"{name} must be a positive number{bound}, got {value!r}")
    return float(value)


def points(name, value, n=None, d=2):
    """``value`` as a finite float ``(n, d)`` array of points; a scalar or a flat list is refused, not broadcast.

    Parameters
    ----------
    name : str
    value : array-like
    n : int, optional
        The number of points required (any when None).
    d : int
        Coordinates per point.

    Returns
    -------
    (n,d) numpy array
        A new array (never a view of ``value``).

    Raises
    ------
    ValueError
        ``"{name} must be an array of shape (n, d) ..., got shape ..."``; NaN or infinite entries, naming the first.
    """
    arr = real_array(name, value)
    if arr.ndim != 2 or arr.shape[1] != d or (n is not None and len(arr) != n):
        want = f"({n}, {d})" if n is not None else f"(n, {d})"
        got = "a scalar" if arr.ndim == 0 else f"shape {arr.shape}"
        raise ValueError(f"{name} must be an array of shape {want}, got {got}")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise ValueError(f"{name} has a NaN or infinite entry (row {int(np.flatnonzero(bad)[0])})")
    return np.array(arr, dtype=float)


def point(name, value, d=2):
    """``value`` as one finite point, a ``(d,)`` float array; a scalar is refused, not broadcast to (x, x).

    Raises
    ------
    ValueError
        ``"{name} must be a point of {d} coordinates, got ..."``.
    """
    arr = real_array(name, value)
    if arr.shape != (d,):
        got = f"the scalar {value!r}" if arr.ndim == 0 else f"shape {arr.shape}"
        raise ValueError(f"{name} must be a point of {d} coordinates, got {got}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be a point of {d} finite coordinates, got NaN or infinite ones: {arr.tolist()}")
    return np.array(arr, dtype=float)


def text(name, value):
    """``value`` checked to be a ``str``; lone surrogates (which no file can encode) become U+FFFD.

    Raises
    ------
    ValueError
        ``"{name} must be a string, got {type}"``.
    """
    if not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {type(value).__name__} {value!r:.80}")
    # a pair of surrogates is one character again; a lone one is replaced, so the text can be written as UTF-8
    return value.encode("utf-16", "surrogatepass").decode("utf-16", "replace")


def write_atomic(path, data, name="path"):
    """Write ``data`` to ``path`` atomically: a temporary file in the same directory, then a rename.

    The one atomic-write policy of the package: operator files, meshes, cache entries and HTML pages use it.

    On any failure the temporary file is removed and ``path`` is left as it was (no empty or partial file).

    Parameters
    ----------
    path : str or os.PathLike
    data : bytes or callable
        The bytes, or ``data(tmp)`` that writes the file ``tmp`` (a str path, for writers that take a name).
    name : str
        The argument's name in error messages.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        ``path`` is not a str or path, or names a directory.
    OSError
        The directory is missing or not writable (the message names the file).
    """
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"{name} must be a str or pathlib.Path, got {type(path).__name__} {path!r:.80}")
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{name} {str(path)!r} is a directory, not a file")
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            if not callable(data):
                fh.write(data)
        if callable(data):
            data(tmp)
        with open(tmp, "rb") as fh:  # on disk before it is renamed into place
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; the file is as readable as one written by open()
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno is not None:  # name the file asked for, not the temporary one
            raise OSError(exc.errno, f"cannot write {name} ({exc.strerror})", str(path)) from exc
        raise
    return path


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def user_stacklevel():
    """The ``stacklevel`` for a ``warnings.warn`` in the calling function that names the user's line.

    The one stacklevel policy of the package: a warning points at the first frame outside ``defop`` (the user's
    call), however deep the library path that warns (a fixed ``stacklevel=2`` points into the library as soon as a
    public function reaches the warning through another one). Python 3.12's ``skip_file_prefixes`` does this;
    defop supports 3.11.

    Returns
    -------
    int
        1 for the caller's own line, +1 per ``defop`` frame above it.
    """
    frame, level = sys._getframe(1), 1
    while frame.f_back is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    return level
