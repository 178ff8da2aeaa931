"""Scenes: a mesh with point handles and sampling regions (layer 2).

:mod:`.regions` are the sampling regions of §3.3, :mod:`.models` the paper's catalogue (Table 1) and
:mod:`.shapes` the :class:`Shape` and its constructors (``load``, ``from_polygon``, ``from_image``,
``from_surface``), from :mod:`.shape`, :mod:`.handles` (handle indices, and in 3D the handle patches that move as one
piece: :func:`.handles.patches`) and :mod:`.planar_shapes`; :mod:`.auto_handles` places handles by itself (one rule
in 2D and 3D) and :mod:`.own_input` reads a user's model from a file of any kind.
"""

from . import auto_handles, handles, models, own_input, placement, planar_shapes, regions, shape, shapes
from .shapes import Shape

__all__ = [
    "Shape",
    "auto_handles",
    "handles",
    "models",
    "own_input",
    "placement",
    "planar_shapes",
    "regions",
    "shape",
    "shapes",
]
