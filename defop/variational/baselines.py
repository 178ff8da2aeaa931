"""Deprecated: the baselines (L-BFGS, libigl's ARAP) moved to :mod:`defop.rivals.baselines`."""

from ..lazy import moved


def _load():
    from ..rivals import baselines

    return baselines


__getattr__, __dir__ = moved(__name__, "defop.rivals.baselines", _load)
