"""Deprecated: the random bistable cases moved to :mod:`defop.lessons.random_branches`."""

from ..lazy import moved


def _load():
    from ..lessons import random_branches

    return random_branches


__getattr__, __dir__ = moved(__name__, "defop.lessons.random_branches", _load)
