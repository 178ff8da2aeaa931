"""Deprecated: the solver's saddle escapes moved to :mod:`defop.variational.escape` (names unchanged)."""

from ..lazy import moved


def _load():
    from . import escape

    return escape


__getattr__, __dir__ = moved(__name__, "defop.variational.escape", _load, ("negative_curvature", "escape"))
