"""Measuring deformations and operators (layer 5): the Fig. 8 error, distortion, trajectories (Figs. 3, 5),
one harness to score DefOp against its rivals (:mod:`.compare`; the rivals are :mod:`defop.rivals`), multi-valued
operators against the solver (:mod:`.branches`) and the mountain pass between two minima (:mod:`.mountain_pass`).

Moved, the old names warn: ``peers`` (:mod:`defop.rivals.peers`), ``figure_data`` and ``random_branches``
(:mod:`defop.lessons`), ``saddle`` (:mod:`.mountain_pass`).
"""

from ..lazy import attach

_MODULES = (
    "branches",
    "compare",
    "distortion",
    "figure_data",
    "metrics",
    "mountain_pass",
    "peers",
    "random_branches",
    "saddle",
    "trajectories",
)
_NAMES = {
    "approximation_error": "metrics",
    "relative_rms_error": "metrics",
    "timing_row": "metrics",
    "flips": "metrics",
    "deformation_summary": "distortion",
}

__getattr__, __dir__ = attach(__name__, _MODULES, _NAMES)
