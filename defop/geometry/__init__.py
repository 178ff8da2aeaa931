"""Geometry: the domain Ω as a simplicial mesh (layer 1).

:class:`Mesh` holds ``V (n, d)`` and ``F (m, d + 1)``. :mod:`.planar` makes planar meshes from polygons,
implicit outlines and pictures (Triangle); :mod:`.volumetric` makes tetrahedral meshes of solids and closed
surfaces (Kuhn cubes); :mod:`.fields` holds the implicit primitives both use; :mod:`.surface_files` reads
PLY, STL, OBJ and OFF files safely (counts checked before allocation, STL welded); :mod:`.coarse` makes a
coarse mesh of the same outline and the prolongation onto the fine one (multilevel training; :mod:`.multilevel` is
its deprecated name). :mod:`.simplices` holds the elements' volumes and facets, :mod:`.mesh_checks` the checks of
a mesh's arrays and :mod:`.mesh_text` the OBJ/OFF mesh files.
"""

from . import (
    coarse,
    fields,
    mesh,
    mesh_checks,
    multilevel,  # noqa: F401 (the deprecated name of .coarse)
    planar,
    simplices,
    surface_files,
    volumetric,
)
from .mesh import Mesh, read_mesh, signed_areas, signed_volumes, write_mesh

__all__ = [
    "Mesh",
    "coarse",
    "fields",
    "mesh",
    "mesh_checks",
    "planar",
    "simplices",
    "surface_files",
    "volumetric",
    "read_mesh",
    "signed_areas",
    "signed_volumes",
    "write_mesh",
]
