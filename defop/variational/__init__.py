"""The variational DefOp D^E (layer 3): deformation energies (Eqs. 10, 11) and problem (6).

The short face: :func:`solve`, :class:`Solver` (``solve``, ``solve_best``, ``verify``), :class:`SolveResult`,
:class:`NotConvergedWarning`, and the baselines :func:`solve_lbfgs`, :func:`solve_libigl_arap`, :func:`start_for`.
The modules, lowest first:

- :mod:`.energies`: ψ of a Jacobian's singular values with its projected Hessian, one face over the closed forms
  of :mod:`.planar` (2×2);
- :mod:`.checks`: the checks of a solve's arguments; :mod:`.backend`: the factorisation back end (qdldl, PARDISO);
- :mod:`.problem`: problem (6) reduced to the free vertices, the Hessian's sparsity pattern and its LDLᵀ;
- :mod:`.inertia`: the one diagonal shift of an exact-Hessian factorisation; :mod:`.kink`: S-ARAP's kink (the held
  set, its pull and certificates, the smoothing continuation);
- :mod:`.newton`: stages, line search, continuation; :mod:`.verify`: the five checks behind ``converged``;
  :mod:`.escape`: negative curvature and the escapes from saddles (``.saddle``, its old name, warns);
- :mod:`.solver`: the :class:`Solver` facade; :mod:`.baselines`: L-BFGS and libigl's ARAP.

Never imports :mod:`defop.operator` (an import-linter contract).
"""

from . import (
    backend,
    baselines,
    checks,
    energies,
    escape,
    newton,
    planar,
    problem,
    saddle,  # noqa: F401 (the old name of .escape, deprecated)
    solver,
    verify,
)
from .baselines import solve_lbfgs, solve_libigl_arap, start_for
from .solver import NotConvergedWarning, Solver, SolveResult, solve

__all__ = [
    "NotConvergedWarning",
    "SolveResult",
    "Solver",
    "backend",
    "baselines",
    "checks",
    "energies",
    "escape",
    "newton",
    "planar",
    "problem",
    "solve",
    "solve_lbfgs",
    "solve_libigl_arap",
    "solver",
    "start_for",
    "verify",
]
