"""Deprecated: the mountain pass between two minima moved to :mod:`defop.analysis.mountain_pass`."""

from ..lazy import moved


def _load():
    from . import mountain_pass

    return mountain_pass


__getattr__, __dir__ = moved(__name__, "defop.analysis.mountain_pass", _load)
