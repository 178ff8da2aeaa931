"""Deprecated: the movable-handle frame's kernel is :func:`defop.operator.kernels.movable_correction`."""

from __future__ import annotations

import warnings


def __getattr__(name):
    if name == "finish_frame":
        warnings.warn(
            "defop.operator.movable_kernels.finish_frame is deprecated: use defop.operator.kernels.movable_correction",
            DeprecationWarning,
            stacklevel=2,
        )
        from .kernels import movable_correction

        return movable_correction
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
