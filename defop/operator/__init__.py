"""The closed-form DefOp (layer 3): D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3), in 2D and 3D.

:mod:`.spatial` is Φ (§3.1), :mod:`.handle_bases` Ψ (Appendix A; :mod:`.radial` its radial kernels), :mod:`.fit`
problem (8). :mod:`.core` is what every operator shares (columns, W_F, factors, the fast state, the checks of Q,
the float32 rule, the extrapolation judgement), :mod:`.compress` the one compression, :mod:`.kernels` the compiled
kernels, :mod:`.io` every kind's files. The operators: :mod:`.defop` (:class:`DefOp`), :mod:`.branched` (one DefOp
per branch of D^E; :mod:`.domains` the domain g_b where a branch exists) and :mod:`.movable` (D(x; P, Q), handles
that move at rest, :class:`MovableOp`). Never imports :mod:`defop.variational`.
"""

from . import branched, compress, core, defop, domains, fit, handle_bases, io, movable, radial, spatial
from .branched import BranchedOperator
from .defop import DefOp, ExtrapolationWarning
from .movable import MovableOp

__all__ = [
    "BranchedOperator",
    "DefOp",
    "ExtrapolationWarning",
    "MovableOp",
    "branched",
    "compress",
    "core",
    "defop",
    "domains",
    "fit",
    "handle_bases",
    "io",
    "movable",
    "radial",
    "spatial",
]
