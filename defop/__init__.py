"""defop: simple approximations of planar deformation operators.

A reproduction of Poranne & Lipman, *Simple Approximations of Planar Deformation Operators*. Use it as
``import defop as dop``. The short face the lessons use:

- ``dop.shapes.load(name)`` (and ``from_polygon``, ``from_image``): a :class:`Shape`;
- ``dop.solve(mesh, handles, targets, energy=...)``: the variational DefOp D^E (problem 6);
- ``dop.train(shape, energy=..., basis=..., m=...)``: the closed-form :class:`DefOp` (problem 8, Eq. 3).

The subpackages, lowest layer first (a module imports only its own subpackage or lower layers; import-linter
checks it): ``geometry`` < ``scene`` < {``variational``, ``operator``} < ``training`` < ``analysis`` < ``view``
< ``editor`` < ``figures``. Everything up to ``training`` imports neither matplotlib nor PyVista nor a widget
library; ``view`` and ``editor`` are imported on first attribute access.
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("defop")
except PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.0.0+unknown"

_SUBPACKAGES = (
    "config",
    "options",
    "geometry",
    "scene",
    "variational",
    "operator",
    "training",
    "analysis",
    "view",
    "editor",
    "figures",
)
#: the public face: name -> (subpackage, attribute)
_FACE = {
    "Mesh": ("geometry", "Mesh"),
    "Shape": ("scene", "Shape"),
    "shapes": ("scene", "shapes"),
    "solve": ("variational", "solve"),
    "DefOp": ("operator", "DefOp"),
    "train": ("training", "train"),
}

__all__ = sorted(_FACE) + ["__version__"]


def __getattr__(name):
    if name in _SUBPACKAGES:
        value = import_module(f".{name}", __name__)
    elif name in _FACE:
        package, attribute = _FACE[name]
        value = getattr(import_module(f".{package}", __name__), attribute)
    else:
        raise AttributeError(f"module 'defop' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + list(_SUBPACKAGES) + list(_FACE))
