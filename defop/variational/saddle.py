"""Deprecated: the solver's saddle escapes moved to :mod:`defop.variational.escape` (names unchanged)."""

from __future__ import annotations

import warnings

from . import escape as _escape_module

_MOVED = ("negative_curvature", "escape")


def __getattr__(name):
    if name in _MOVED:
        warnings.warn(
            f"defop.variational.saddle.{name} moved to defop.variational.escape.{name}",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(_escape_module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
