"""defop: simple approximations of planar deformation operators.

A reproduction of Poranne & Lipman, *Simple Approximations of Planar
Deformation Operators*. Use it as ``import defop as dop``.

The core modules (mesh, shapes, energies, solve, spatial, handle_bases,
sampling, fit, operator, train, analysis) import neither matplotlib nor
pyvista nor ipywidgets. The presentation modules (``plot``, ``render``,
``widgets``, ``figures``) are imported lazily on first attribute access,
e.g. ``dop.plot``.
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("defop")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"

_SUBMODULES = (
    "mesh",
    "shapes",
    "polygon",
    "meshing",
    "outlines",
    "models",
    "regions",
    "energies",
    "distortion",
    "solve",
    "spatial",
    "handle_bases",
    "sampling",
    "fit",
    "operator",
    "train",
    "analysis",
    "plot",
    "render",
    "widgets",
    "editor_state",
    "browser",
    "figures",
    "config",
    "trajectories",
    "cache",
    "peers",
    "compare",
    "warp",
    "plot_peers",
    "figure_data",
)


def __getattr__(name):
    if name in _SUBMODULES:
        module = import_module(f".{name}", __name__)
        globals()[name] = module
        return module
    raise AttributeError(f"module 'defop' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_SUBMODULES))
