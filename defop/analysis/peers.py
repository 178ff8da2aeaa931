"""Deprecated: the peers moved to :mod:`defop.rivals.peers` (with :mod:`defop.rivals`' other rival methods)."""

from ..lazy import moved


def _load():
    from ..rivals import peers

    return peers


__getattr__, __dir__ = moved(__name__, "defop.rivals.peers", _load)
