"""Volumetric meshing: closed solids → tetrahedral meshes (layer 1).

:mod:`.grid` splits the cubes of a regular grid into Kuhn tetrahedra and cleans a cube set into one
solid with a manifold boundary; :mod:`.mesher` keeps the cubes inside a solid (an implicit field or a
closed triangle surface) and snaps the boundary onto its surface; :mod:`.surface` checks closed
triangle surfaces, tests inside by libigl's generalised winding number and embeds a fine surface in
the tetrahedra (barycentric coordinates); :mod:`.examples` generates example surfaces (a torus).
"""

from . import grid, mesher
from .grid import kuhn_tets
from .mesher import tet_mesh

__all__ = ["grid", "mesher", "kuhn_tets", "tet_mesh"]
