"""Measuring deformations and operators (layer 5): the Fig. 8 error, distortion, trajectories (Figs. 3, 5),
the peers (MLS, TPS warps, BBW + LBS, biharmonic coordinates, ARAP iterations), figure data and multi-valued
operators against the solver (:mod:`.branches`, on random bistable shapes: :mod:`.random_branches`) and the saddle
between two minima (:mod:`.saddle`).
"""

from ..lazy import attach

_MODULES = (
    "branches",
    "compare",
    "distortion",
    "figure_data",
    "metrics",
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
