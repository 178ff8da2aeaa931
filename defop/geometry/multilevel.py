"""Deprecated name of :mod:`defop.geometry.coarse` (coarse meshes and the prolongation for multilevel training).

Every name still resolves here, with a ``DeprecationWarning``; import it from :mod:`defop.geometry.coarse`.
"""

from ..lazy import moved


def _load():
    from . import coarse

    return coarse


__getattr__, __dir__ = moved(__name__, "defop.geometry.coarse", _load)
