"""Deprecated name of :mod:`defop.geometry.coarse` (coarse meshes and the prolongation for multilevel training).

Every name still resolves here, with a ``DeprecationWarning``; import it from :mod:`defop.geometry.coarse`.
"""

from __future__ import annotations

import warnings

from . import coarse

__all__ = list(coarse.__all__)


def __getattr__(name):
    """A name of :mod:`defop.geometry.coarse`, with a ``DeprecationWarning`` naming the new module."""
    value = getattr(coarse, name)  # AttributeError for a name coarse does not have either
    warnings.warn(
        f"defop.geometry.multilevel is renamed defop.geometry.coarse; import {name} from there",
        DeprecationWarning,
        stacklevel=2,
    )
    return value
