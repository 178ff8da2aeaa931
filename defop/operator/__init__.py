"""The closed-form DefOp (layer 3): D(x, Q) = Σ_ij C_ij φ_i(x) ψ_j(Q) (Eq. 3).

:mod:`.spatial` is Φ (§3.1), :mod:`.handle_bases` Ψ (Appendix A), :mod:`.fit` problem (8) and
:mod:`.defop` the trained operator :class:`DefOp`. Never imports :mod:`defop.variational`.
"""

from . import defop, fit, handle_bases, spatial
from .defop import DefOp, ExtrapolationWarning

__all__ = ["DefOp", "ExtrapolationWarning", "defop", "fit", "handle_bases", "spatial"]
