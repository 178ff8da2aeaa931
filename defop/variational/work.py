"""Work: what a process's factorisations have cost, counted from symbolic data (never from time).

Every numeric factorisation of a reduced Hessian (:meth:`defop.variational.problem.ReducedHessian.factorise`; an
equal matrix re-used is none) adds the nonzeros of its factor L (the back end's: qdldl's AMD, PARDISO's iparm[17],
SuperLU's L and U) plus :data:`ITERATION`, the fixed part of the Newton iteration around it (assembly, line search,
checks). The count depends only on what was solved and on the back end, not on the machine's speed or load, so a
budget counted in it (:func:`defop.training.movable_budget.train_within`) gives the same m on every machine where
the solves are the same. :func:`total` is this process's running sum; the training engine reads it around each
sample where the sample runs (:mod:`defop.training.work`).
"""

from __future__ import annotations

__all__ = ["ITERATION", "add", "total"]

#: what a factorisation adds beside its factor's nonzeros, in nonzeros: the share of a Newton iteration's CPU that
#: does not grow with the factor. Chosen once, from the CPU seconds of fixed-P and joint trainings measured side by
#: side on the bar, the aleph, the octopus and bar_3d (benchmarks/README.md, 2026-12-02, fifth part): with it the
#: ratio of two trainings' work is their CPU seconds' ratio within 6% on all four (without it, up to 1.81x).
ITERATION = 12_000

_TOTAL = [0.0]


def add(nonzeros):
    """Count one factorisation of ``nonzeros`` factor nonzeros."""
    _TOTAL[0] += float(nonzeros) + ITERATION


def total():
    """This process's factorisation work so far (:func:`add` summed over its factorisations)."""
    return _TOTAL[0]
