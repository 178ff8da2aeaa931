"""Measuring deformations and operators (layer 5): the Fig. 8 error, distortion, trajectories (Figs. 3, 5),
the peers (MLS, TPS warps, BBW + LBS, biharmonic coordinates, ARAP iterations) and figure data.
"""

from importlib import import_module

_MODULES = ("compare", "distortion", "figure_data", "metrics", "peers", "trajectories")
_NAMES = {
    "approximation_error": "metrics",
    "relative_rms_error": "metrics",
    "timing_row": "metrics",
    "flips": "metrics",
    "deformation_summary": "distortion",
}


def __getattr__(name):  # modules drawn in on first use: peers needs libigl's bindings, which most analyses do not
    if name in _MODULES:
        module = import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    if name in _NAMES:
        value = getattr(import_module(f".{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_MODULES) + list(_NAMES))
