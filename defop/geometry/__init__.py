"""Geometry: the domain Ω as a simplicial mesh (layer 1).

:class:`Mesh` holds ``V (n, d)`` and ``F (m, d + 1)``. :mod:`.planar` makes planar meshes from polygons,
implicit outlines and pictures (Triangle).
"""

from . import mesh, planar
from .mesh import Mesh, read_mesh, signed_areas, signed_volumes, write_mesh

__all__ = ["Mesh", "mesh", "planar", "read_mesh", "signed_areas", "signed_volumes", "write_mesh"]
