"""Deprecated module path: certification lives in :mod:`defop.training.branches` (:mod:`.branches.certify`)."""

from ..lazy import moved


def _load():
    from . import branches

    return branches


__getattr__, __dir__ = moved(
    __name__,
    "defop.training.branches",
    _load,
    ("Certified", "bracket_fold", "certify", "certify_branches", "grid_neighbours", "refine_segments"),
)
