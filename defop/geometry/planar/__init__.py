"""Planar geometry: polygons and their checks, Triangle meshing, implicit outlines and image silhouettes."""

from . import meshing, outlines, polygon
from .meshing import triangulate
from .polygon import polygon_area

__all__ = ["meshing", "outlines", "polygon", "polygon_area", "triangulate"]
