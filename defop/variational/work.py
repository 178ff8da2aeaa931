"""Work: what a process's factorisations have cost, counted from symbolic data (never from time).

Every numeric factorisation of a reduced Hessian (:meth:`defop.variational.problem.ReducedHessian.factorise`; an
equal matrix re-used is none) adds the nonzeros of its factor L (the back end's: qdldl's AMD, PARDISO's iparm[17],
SuperLU's L and U), plus the rest of the Newton iteration around it: :data:`ITERATION` (its fixed part: Python,
line search, checks) and :data:`HESSIAN` per nonzero of the factorised Hessian K (what grows with the mesh: the
element kernels' gradient and Hessian, the energies of the line search, the solves). The count depends only on
what was solved, on the back end and on whether factorisations are re-used (``DEFOP_REUSE``: a CG step is no
factorisation), not on the machine's speed or load, so a budget counted in it
(:func:`defop.training.movable_budget.train_within`) gives the same m wherever the same back end runs the same solves
(:func:`defop.training.work.units` records which). :func:`total` is this process's running sum; the training engine
reads it around each sample where the sample runs (:mod:`defop.training.work`).
"""

from __future__ import annotations

import math

__all__ = ["HESSIAN", "ITERATION", "add", "total"]

#: what a factorisation adds beside its factor's and its Hessian's nonzeros, in factor nonzeros (one is about 20 ns of
#: CPU, qdldl's numeric factorisation on the bar and the aleph): the share of a Newton iteration's CPU that does not
#: grow with the mesh. With :data:`HESSIAN`, fitted once (least squares, relative) to the CPU seconds outside the
#: factorisations and the fit of the fixed-P training at m = 200 and of the joint training within 5x, on the bar and
#: the aleph at full size (benchmarks/README.md, 2026-12-02, sixth part: they are the fit, within 1.5%; the octopus is
#: held out). Before (12,000, no Hessian term) a fixed-P training's many small coarse iterations counted as much as
#: fine ones: its work was overstated against the joint training's all-fine iterations and a 5.00x work budget cost
#: 5.4-6.2x the CPU seconds at full size; with all the sixth part's terms 4.84-5.73x (bar, three runs), 5.49x (aleph)
#: and 5.30x (octopus): about 5% still unpredicted, a run's CPU ratio scattering by ±8% at the same work.
ITERATION = 14_000

#: what a factorisation adds per nonzero of its Hessian K (the upper triangle factorised), in factor nonzeros: the
#: Newton iteration's assembly and evaluations, which grow with the mesh (fitted with :data:`ITERATION`)
HESSIAN = 3.3

_TOTAL = [0.0]


def add(nonzeros, hessian=0):
    """Count one factorisation of ``nonzeros`` factor nonzeros, of a Hessian with ``hessian`` nonzeros: the factor's
    nonzeros + :data:`ITERATION` + :data:`HESSIAN` × ``hessian`` rounded to a whole number (so that a sample's work,
    a difference of two running totals, is the same whatever was counted before it).

    Raises
    ------
    ValueError
        A negative or non-finite count (nothing counted).
    """
    nonzeros, hessian = float(nonzeros), float(hessian)
    if not (math.isfinite(nonzeros) and math.isfinite(hessian) and nonzeros >= 0 and hessian >= 0):
        raise ValueError(f"a factorisation's nonzeros must be finite and >= 0, got {nonzeros!r} and {hessian!r}")
    _TOTAL[0] += nonzeros + ITERATION + round(HESSIAN * hessian)  # whole numbers: sums and differences are exact


def total():
    """This process's factorisation work so far (:func:`add` summed over its factorisations)."""
    return _TOTAL[0]
