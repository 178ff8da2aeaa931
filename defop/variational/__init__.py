"""The variational DefOp D^E (layer 3): deformation energies (Eqs. 10, 11) and problem (6).

The short face: :func:`solve`, :class:`Solver` (``solve``, ``solve_best``, ``verify``), :class:`SolveResult`,
:class:`NotConvergedWarning`. The baselines (L-BFGS, libigl's ARAP) are in :mod:`defop.rivals.baselines`; their
old names here (``baselines``, ``solve_lbfgs``, ``solve_libigl_arap``, ``start_for``) warn. The modules, lowest
first:

- :mod:`.energies`: ψ of a Jacobian's singular values with its projected Hessian, one face over the closed forms
  of :mod:`.planar` (2×2);
- :mod:`.checks`: the checks of a solve's arguments; :mod:`.backend`: the factorisation back end (qdldl, PARDISO);
- :mod:`.problem`: problem (6) reduced to the free vertices, the Hessian's sparsity pattern and its LDLᵀ;
- :mod:`.inertia`: the one diagonal shift of an exact-Hessian factorisation; :mod:`.kink`: S-ARAP's kink (the held
  set, its pull and certificates, the smoothing continuation);
- :mod:`.newton`: stages, line search, continuation; :mod:`.verify`: the five checks behind ``converged``;
  :mod:`.escape`: negative curvature and the escapes from saddles (``.saddle``, its old name, warns);
- :mod:`.backend`: the sparse factorisation's back end; :mod:`.checks`: the argument checks;
- :mod:`.solver`: the :class:`Solver` facade.

Never imports :mod:`defop.operator` (an import-linter contract).
"""

from importlib import import_module

from ..lazy import moved
from . import (
    backend,
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
from .solver import NotConvergedWarning, Solver, SolveResult, solve

__all__ = [
    "NotConvergedWarning",
    "SolveResult",
    "Solver",
    "backend",
    "checks",
    "energies",
    "escape",
    "newton",
    "planar",
    "problem",
    "solve",
    "solver",
    "verify",
]


def _load_baselines():
    from ..rivals import baselines as moved_baselines

    return moved_baselines


_BASELINES = ("solve_lbfgs", "solve_libigl_arap", "start_for")
_baselines_getattr, _ = moved(__name__, "defop.rivals.baselines", _load_baselines, _BASELINES, stacklevel=3)


def __getattr__(name):
    """The baselines' old names (deprecated; they moved to :mod:`defop.rivals.baselines`): each warns."""
    if name == "baselines":  # the old module, whose names warn
        return import_module(".baselines", __name__)
    return _baselines_getattr(name)
