"""Planar geometry: polygons and their checks, Triangle meshing, implicit outlines and image silhouettes."""

from . import meshing, outlines, polygon, silhouette
from .meshing import triangulate
from .polygon import polygon_area

__all__ = ["meshing", "outlines", "polygon", "polygon_area", "silhouette", "triangulate"]
