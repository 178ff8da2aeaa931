"""Run-time settings read from the environment.

``DEFOP_FAST=1``
    Fast mode for CI: notebooks shrink sample counts but keep their claims.
``DEFOP_CACHE``
    Directory of the on-disk cache of trained operators and sampled ground
    truths (default: ``~/.cache/defop``). ``DEFOP_CACHE=off`` disables it.
``DEFOP_N_JOBS``
    Default number of parallel workers for sample solves (default: all cores).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["fast_mode", "cache_dir", "n_jobs", "pick"]


def fast_mode() -> bool:
    """True when ``DEFOP_FAST`` is set to a true value (1, true, yes, on)."""
    return os.environ.get("DEFOP_FAST", "").strip().lower() in ("1", "true", "yes", "on")


def pick(full, fast):
    """``fast`` in fast mode, else ``full``: ``m = dop.config.pick(400, 60)``."""
    return fast if fast_mode() else full


def cache_dir() -> Path | None:
    """The cache directory (created on demand), or None when caching is off."""
    value = os.environ.get("DEFOP_CACHE", "").strip()
    if value.lower() in ("off", "0", "none", "false"):
        return None
    path = Path(value).expanduser() if value else Path.home() / ".cache" / "defop"
    path.mkdir(parents=True, exist_ok=True)
    return path


def n_jobs() -> int:
    """Default worker count for joblib: ``DEFOP_N_JOBS`` or every core (-1)."""
    value = os.environ.get("DEFOP_N_JOBS", "").strip()
    return int(value) if value else -1
