"""The variational DefOp D^E (layer 3): deformation energies (Eqs. 10, 11) and problem (6).

:mod:`.energies` evaluates ψ of a Jacobian's singular values with its projected Hessian; :mod:`.solver`
minimises Σ_t A_t ψ(J_t) with the handles as hard constraints and verifies the minimum it returns.
Never imports :mod:`defop.operator.defop` (an import-linter contract).
"""

from . import energies, solver
from .solver import NotConvergedWarning, Solver, solve

__all__ = ["NotConvergedWarning", "Solver", "energies", "solve", "solver"]
