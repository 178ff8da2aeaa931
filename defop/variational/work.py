"""Work: what a process's factorisations have cost, counted from symbolic data (never from time).

Every numeric factorisation of a reduced Hessian (:meth:`defop.variational.problem.ReducedHessian.factorise`; an
equal matrix re-used is none) adds the nonzeros of its factor L (the back end's: qdldl's AMD, PARDISO's iparm[17],
SuperLU's L and U) plus :data:`ITERATION`, the fixed part of the Newton iteration around it (assembly, line search,
checks). The count depends only on what was solved, on the back end and on whether factorisations are re-used
(``DEFOP_REUSE``: a CG step is no factorisation), not on the machine's speed or load, so a budget counted in it
(:func:`defop.training.movable_budget.train_within`) gives the same m wherever the same back end runs the same solves
(:func:`defop.training.work.units` records which). :func:`total` is this process's running sum; the training engine
reads it around each sample where the sample runs (:mod:`defop.training.work`).
"""

from __future__ import annotations

__all__ = ["ITERATION", "add", "total"]

#: what a factorisation adds beside its factor's nonzeros, in nonzeros: the share of a Newton iteration's CPU that
#: does not grow with the factor. Fitted once to the CPU seconds of fixed-P and joint trainings measured side by side
#: on the bar, the aleph and the octopus (benchmarks/README.md, 2026-12-02, fifth part: those three are the fit, not a
#: test); the one shape held out, bar_3d, gave a CPU/work ratio of 0.97. At full size (a 5.00x work budget) the CPU
#: ratio was 20-25% above the work ratio (bar 6.03x, aleph 6.23x). Without it, up to 1.81x apart.
ITERATION = 12_000

_TOTAL = [0.0]


def add(nonzeros):
    """Count one factorisation of ``nonzeros`` factor nonzeros."""
    _TOTAL[0] += float(nonzeros) + ITERATION


def total():
    """This process's factorisation work so far (:func:`add` summed over its factorisations)."""
    return _TOTAL[0]
