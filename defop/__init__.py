"""defop: simple approximations of planar deformation operators.

A reproduction of Poranne & Lipman, *Simple Approximations of Planar Deformation Operators*. Use it as
``import defop as dop``. The short face the lessons use:

- ``dop.shapes.load(name)`` (and ``from_polygon``, ``from_image``): a :class:`Shape`;
- ``dop.solve(mesh, handles, targets, energy=...)``: the variational DefOp D^E (problem 6);
- ``dop.train(shape, energy=..., basis=..., m=...)``: the closed-form :class:`DefOp` (problem 8, Eq. 3);
- ``dop.own_model("outline.csv")``: your own model's file (polygon, picture or surface) to a page that drags it, in
  one call (``python -m defop page outline.csv`` on the command line).

The subpackages, lowest layer first (a module imports only its own subpackage or lower layers; import-linter
checks it): ``geometry`` < ``scene`` < {``variational``, ``operator``} < {``training``, ``rivals``} < ``analysis``
< ``view`` < ``editor`` < ``lessons`` < ``figures``. Everything up to ``analysis`` imports neither matplotlib nor
PyVista nor a widget library; ``view`` and ``editor`` are imported on first attribute access. ``rivals`` holds the
methods DefOp is compared with, ``lessons`` the notebooks' own figure data.
"""

from importlib.metadata import PackageNotFoundError, version

from .lazy import attach

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
    "rivals",
    "analysis",
    "view",
    "editor",
    "lessons",
    "figures",
)
#: the public face: name -> the subpackage it comes from
_FACE = {
    "Mesh": "geometry",
    "Shape": "scene",
    "shapes": "scene",
    "solve": "variational",
    "DefOp": "operator",
    "train": "training",
    "own_model": "editor",
}

__all__ = sorted(_FACE) + ["__version__"]

__getattr__, __dir__ = attach(__name__, _SUBPACKAGES, _FACE)
