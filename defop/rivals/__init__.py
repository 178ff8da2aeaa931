"""The rival methods (layer 4, beside :mod:`defop.training`): what people use instead of DefOp, for comparison.

- :mod:`.peers`: the closed-form point-handle deformations of notebooks 12, 13 and 14 behind one interface,
  :class:`~.peers.Peer` (:func:`~.peers.make_peer`, :func:`~.peers.make_peers`): MLS and the TPS warp
  (:mod:`.closed_forms`), BBW + LBS, biharmonic coordinates and ARAP iterations (:mod:`.libigl`), with their
  shared input checks (:mod:`.checks`);
- :mod:`.baselines`: other solvers of problem (6) on the same energies, verified by the same checks: L-BFGS and
  libigl's local–global ARAP.

Imports :mod:`defop.variational` (its problem, line search and checks) and :mod:`defop.options`; the core below
never imports it, and it imports no plotting library (import-linter contracts). Its modules load on first access
(libigl is heavy).
"""

from ..lazy import attach

_MODULES = ("baselines", "checks", "closed_forms", "libigl", "peers")
_NAMES = {
    "KINDS": "peers",
    "Peer": "peers",
    "make_peer": "peers",
    "make_peers": "peers",
    "solve_lbfgs": "baselines",
    "solve_libigl_arap": "baselines",
    "start_for": "baselines",
}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)
