"""Training a DefOp (layer 4, §3.3): sample Q_k, solve D^E at each (in parallel, cached), fit.

:mod:`.sampling` draws the Q_k, :mod:`.cache` stores ground truths and operators on disk, :mod:`.solves` (the
sample engine) is the one code that solves problem (6) for many samples and :mod:`.portfolios` builds the training
policies on it; :mod:`.bootstrap` runs the pipeline (:func:`train`); :mod:`.adaptive` chooses the samples where
the operator is least certain (:func:`train_adaptive`); :mod:`.branches` finds every branch of D^E and fits a
multi-valued operator and certifies where each branch is present and absent;
:mod:`.multilevel` is ``train``'s multilevel policy (decisions on a coarse mesh), :mod:`.movable` trains handles
that move at rest (:func:`train_movable`; :mod:`.movable_budget` within a budget counted in :mod:`.work`,
:func:`train_within`) and :mod:`.reference` gives held-out comparisons a truth independent of
the operator under test.
"""

from . import (
    adaptive,
    bootstrap,
    branches,
    cache,
    movable,
    movable_budget,
    multilevel,
    paths,
    portfolios,
    reference,
    sampling,
    solves,
    work,
)
from .adaptive import train_adaptive
from .bootstrap import TrainingRecord, held_out, min_samples, solve_samples, train
from .movable import train_movable
from .movable_budget import train_within

__all__ = [
    "TrainingRecord",
    "adaptive",
    "bootstrap",
    "branches",
    "cache",
    "held_out",
    "min_samples",
    "movable",
    "movable_budget",
    "multilevel",
    "paths",
    "portfolios",
    "reference",
    "sampling",
    "solve_samples",
    "solves",
    "train",
    "train_adaptive",
    "train_movable",
    "train_within",
    "work",
]


def __getattr__(name):
    if name == "branch_domains":  # the deprecated module path: imported (and warning) on first use only
        import importlib

        return importlib.import_module(".branch_domains", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
