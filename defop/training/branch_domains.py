"""Deprecated module path: certification lives in :mod:`defop.training.branches` (:mod:`.branches.certify`)."""

from __future__ import annotations

import warnings

from .branches.certify import Certified, bracket_fold, certify, certify_branches, refine_segments
from .branches.grid import grid_neighbours

__all__ = ["Certified", "bracket_fold", "certify", "certify_branches", "grid_neighbours", "refine_segments"]

warnings.warn(
    "defop.training.branch_domains is deprecated: import certify_branches, certify, ... from defop.training.branches",
    DeprecationWarning,
    stacklevel=2,
)
