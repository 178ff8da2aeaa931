"""Validation of user options, one message style: the option's name, what it must be, what was given."""

from __future__ import annotations

import numbers

import numpy as np

from . import config


def integer(name, value, minimum=None, maximum=None):
    """``value`` as an int, checked to be an integer (an integral float is accepted) within bounds.

    Raises
    ------
    ValueError
        ``"{name} must be an integer >= {minimum}, got {value!r}"`` (bools, fractions, NaN, strings).
    """
    ok = isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))
    if not ok and isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        ok = bool(np.isfinite(value)) and float(value).is_integer()
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


def n_jobs(value):
    """A joblib worker count: None (the ``DEFOP_N_JOBS`` default, checked here) or a non-zero integer."""
    if value is None:
        config.n_jobs()  # a bad DEFOP_N_JOBS fails now, not after the first stage of work
        return None
    jobs = integer("n_jobs", value)
    if jobs == 0:
        raise ValueError("n_jobs must be a non-zero integer (-1: every core, 1: this process), got 0")
    return jobs


def seed(value):
    """A sampling seed: a non-negative integer (``numpy.random.default_rng(seed)``)."""
    return integer("seed", value, minimum=0)


def real_array(name, value):
    """``value`` as a float numpy array, refusing what a float cast would silently mangle.

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
    return arr.astype(float, copy=False)


def positive(name, value):
    """``value`` as a float, checked to be a finite real number > 0.

    Raises
    ------
    ValueError
        ``"{name} must be a positive number, got {value!r}"`` (bools, strings, NaN, inf, 0 and below).
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if not ok or not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)
