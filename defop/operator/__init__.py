"""The closed-form DefOp (layer 3): D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3), in 2D and 3D.

:mod:`.spatial` is Φ (§3.1), :mod:`.handle_bases` Ψ (Appendix A), :mod:`.fit` problem (8),
:mod:`.defop` the trained operator :class:`DefOp` and its evaluation paths, :mod:`.branched` the multi-valued
operator (one DefOp per branch of D^E; :mod:`.domains` the domain g_b where a branch exists), :mod:`.compress` its
compression and :mod:`.io` its files; :mod:`.movable` is D(x; P, Q), handles that move at rest (:class:`MovableOp`).
Never imports :mod:`defop.variational`.
"""

from . import branched, compress, defop, domains, fit, handle_bases, io, movable, spatial
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
    "defop",
    "domains",
    "fit",
    "handle_bases",
    "io",
    "movable",
    "spatial",
]
