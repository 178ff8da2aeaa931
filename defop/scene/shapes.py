"""Shapes: a mesh of Ω with point handles and sampling regions; the public façade for geometry.

A :class:`Shape` is a mesh of Ω with its point handles p_l (mesh vertices), which of them move
(the variables Q of the handle basis Ψ) and which stay fixed (the bar's clamped end, the blue
handles of Fig. 4), and one sampling region per moving handle (§3.3: where the training
configurations Q_k are drawn).

Shapes come from a polygon (:func:`from_polygon`), an image (:func:`from_image`), a closed triangle
surface (:func:`from_surface`, a tetrahedral mesh in 3D) or the catalogue (:func:`load`, :func:`names`).
The work is done by one module per concern, whose public modules are:

- :mod:`defop.scene.shape`: the :class:`Shape` itself; :mod:`defop.scene.handles`: handle indices and points;
- :mod:`defop.scene.planar_shapes`: :func:`from_polygon` and :func:`from_image`;
- :mod:`defop.geometry.planar.polygon`: polygon geometry and validation (what Triangle can mesh);
- :mod:`defop.geometry.planar.meshing`: Triangle (:func:`triangulate`);
- :mod:`defop.geometry.planar.outlines`: implicit fields and image silhouettes;
- :mod:`defop.scene.models`: the paper's models (``bar``, ``u_shape``, ``gingerbread``, ``aleph``,
  ``octopus``, ``crab``, ``dino``);
- :mod:`defop.geometry.volumetric`: tetrahedral meshes of solids and closed surfaces;
- :mod:`defop.scene.regions`: sampling regions.
"""

from __future__ import annotations

import functools

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from ..geometry.planar.meshing import MAX_VERTICES, check_n_vertices
from ..geometry.volumetric import surface as surfaces
from . import auto_handles as auto
from .handles import Patches as Patches  # re-exported
from .handles import check_handles_span as check_handles_span  # re-exported
from .handles import handle_indices as handle_indices  # re-exported
from .handles import handle_vertices
from .handles import patches as patches  # re-exported
from .models import check_name, default_vertices, model
from .models import dim as model_dim
from .planar_shapes import MAX_AUTO_HANDLES as MAX_AUTO_HANDLES  # re-exported
from .planar_shapes import from_image, from_polygon, image_frame
from .regions import REGION_KINDS
from .shape import Shape

__all__ = [
    "Shape",
    "load",
    "names",
    "from_polygon",
    "from_image",
    "image_frame",
    "from_surface",
    "default_vertices",
    "REGION_KINDS",
    "MAX_VERTICES",
]


def names(dim=2):
    """Names of the built-in shapes.

    Parameters
    ----------
    dim : {2, 3, None}
        2 (default): the paper's planar models; 3: the solids (tetrahedral meshes); None: all.

    Returns
    -------
    names : list of str
    """
    from .models import CATALOGUE, SOLIDS

    if dim not in (2, 3, None):
        raise ValueError(f"dim must be 2, 3 or None (all), got {dim!r}")
    return [*(CATALOGUE if dim in (2, None) else ()), *(SOLIDS if dim in (3, None) else ())]


@functools.lru_cache(maxsize=32)
def _load(name, n_vertices):
    m = model(name)
    if model_dim(name) == 3:
        mesh = m.mesh(n_vertices or default_vertices(name))
        surface = None if m.surface is None else surfaces.EmbeddedSurface.embed(mesh, *m.surface)
        idx = handle_vertices(mesh, m.handles)
        return Shape(m.name, mesh, idx, m.moving, list(m.regions), m.description, [], surface)
    return from_polygon(
        m.outer,
        m.holes,
        m.handles,
        m.moving,
        m.regions,
        n_vertices=n_vertices or default_vertices(name),
        name=m.name,
        description=m.description,
    )


def load(name, n_vertices=None):
    """One of the catalogue's models as a :class:`Shape`.

    Parameters
    ----------
    name : str
        One of :func:`names` (``names(dim=3)`` for the solids, meshed into tetrahedra).
    n_vertices : int, optional
        About how many mesh vertices, 20 to ``MAX_VERTICES`` (default: near Table 1).

    Returns
    -------
    shape : Shape
        A fresh copy (safe to modify).

    Raises
    ------
    ValueError
        Unknown name (the message lists the known ones) or a bad vertex count.
    """
    check_name(name)
    if n_vertices is not None:
        n_vertices = check_n_vertices(n_vertices)
        if n_vertices < 20:
            raise ValueError(f"n_vertices must be an integer >= 20, got {n_vertices!r}")
    s = _load(name, n_vertices)
    mesh = Mesh(s.mesh.V.copy(), s.mesh.F.copy())
    return Shape(
        s.name,
        mesh,
        s.handles.copy(),
        s.moving.copy(),
        list(s.regions),
        s.description,
        [L.copy() for L in s.outline],
        s.surface,  # read-only by convention; the same for every copy
    )


def from_surface(
    V,
    F=None,
    handles=None,
    moving=None,
    regions=None,
    n_vertices=2000,
    name="surface",
    description="",
    region_scale=0.25,
    overlapping_parts=False,
    weld_tolerance=None,
    n_auto_handles=3,
    patch_size=None,
):
    """A 3D :class:`Shape` from a closed triangle surface or a surface file: a tetrahedral mesh of the solid it bounds.

    The solid is meshed by Kuhn cubes (:func:`defop.geometry.volumetric.surface.surface_mesh`: the cubes
    whose centre has winding number ≥ 1/2, boundary snapped toward the surface while every tetrahedron
    keeps a tenth of its volume), the same on every CPU, and the same for every copy of the surface with the same
    canonical coordinates (:func:`defop.geometry.volumetric.surface.canonical_surface`: rounded to float32, then to a
    grid of about 1e-6 of the diagonal; an STL and its OBJ, or a copy of a surface on that grid perturbed by less
    than 1.9e-7 of the diagonal), so such copies share their cache entries. The surface is embedded in the tetrahedra
    (``shape.surface``) so that it can be drawn deformed.

    Parameters
    ----------
    V : (n,3) numpy array, or str or pathlib.Path
        Surface vertices, or the path of a PLY, STL, OBJ or OFF file
        (read by :func:`defop.geometry.volumetric.surface.read_surface`; then F is not given).
    F : (k,3) int numpy array
        Surface triangles: a closed, consistently oriented, manifold surface that does not cross itself
        (inward-facing orientation is flipped).
    handles : (h,3) numpy array, optional
        Handle points inside the solid; each becomes its nearest mesh vertex (with ``patch_size``, a patch around
        it). At least 3 vertices in all, not all on one line (a rotation about that line would be free). Default:
        ``n_auto_handles`` patches of :data:`defop.scene.auto_handles.PATCH_SIZE` vertices at the extremities of
        the surface (:func:`defop.scene.auto_handles.extremities`, the rule of 2D shapes too).
    moving : (h,) bool numpy array, optional
        Which handles (patches) move (default: all); a patch's vertices share its flag.
    regions, name, description, region_scale
        As in :func:`defop.scene.planar_shapes.from_polygon`, one region per moving vertex; the default regions
        are balls (``{"kind": "ball", "radius": region_scale × bounding-box diagonal / 2}``).
        Moving handles whose balls overlap (a patch's vertices) form one handle patch
        (:func:`defop.scene.handles.patches`), which training moves rigidly by default (:func:`defop.training.train`'s
        ``sampling``).
    n_vertices : int
        About how many tetrahedral mesh vertices, 100 to ``MAX_VERTICES``.
    overlapping_parts : bool
        Accept separate closed parts that cross each other, meshed as their union.
    weld_tolerance : float, optional
        With a path: also merge vertices closer than this fraction of the bounding-box diagonal (a surface
        whose copies of one vertex differ slightly reads as open without it).
    n_auto_handles : int
        How many patches to place without ``handles``.
    patch_size : int, optional
        Vertices per handle: the handle's vertex and its nearest ones (:func:`defop.scene.auto_handles.patches`);
        default 1 for given handles, :data:`defop.scene.auto_handles.PATCH_SIZE` for automatic ones.

    Returns
    -------
    shape : Shape
        Its ``surface`` holds the surface embedded in the tetrahedra.

    Raises
    ------
    ValueError
        A surface file that cannot be read (the message names it), an open or non-manifold surface (the message
        names the edge or vertex, and for an open one the weld_tolerance that would close it), inconsistent orientation,
        two triangles that cross (pairs sharing a vertex are not tested:
        :func:`defop.geometry.volumetric.surface.self_intersections`), a handle outside the mesh, handles
        on one line, or a bad vertex count.
    """
    import os

    if isinstance(V, (str, bytes, os.PathLike)):
        if F is not None:
            raise ValueError("from_surface: give a surface file's path alone, or V and F, not a path and F")
        V, F = surfaces.read_surface(V, weld_tolerance=weld_tolerance)
    elif F is None:
        raise ValueError("from_surface needs F, the (k,3) surface triangles, with V (or the path of a surface file)")
    elif weld_tolerance is not None:
        raise ValueError("weld_tolerance applies to a surface file's path; weld V and F with surface_files.weld")
    if handles is None:
        n_auto_handles = opt.integer("n_auto_handles", n_auto_handles, minimum=1, maximum=MAX_AUTO_HANDLES)
    n_vertices = check_n_vertices(n_vertices)
    if n_vertices < 100:
        raise ValueError(f"n_vertices must be an integer >= 100, got {n_vertices!r}")
    V, F = surfaces.check_surface(V, F, overlapping_parts=overlapping_parts)
    mesh = surfaces.surface_mesh(V, F, n_vertices, checked=True)
    if handles is None:
        groups = auto.patches(mesh, auto.extremities(mesh, n_auto_handles), patch_size)
    else:
        groups = auto.patches(mesh, handle_vertices(mesh, handles), 1 if patch_size is None else patch_size)
    idx = np.concatenate(groups)
    if moving is None:
        moving = np.ones(len(idx), bool)
    else:  # Shape checks the flags
        moving = np.asarray(moving).ravel()
        if len(moving) != len(groups):
            raise ValueError(f"moving has {len(moving)} entries for {len(groups)} handles")
        moving = np.repeat(moving, [len(g) for g in groups])
    if regions is None:
        r = region_scale * mesh.bbox_diagonal / 2
        regions = [{"kind": "ball", "radius": r} for _ in range(int(np.count_nonzero(moving)))]
    surface = surfaces.EmbeddedSurface.embed(mesh, V, F)
    return Shape(name, mesh, idx, moving, list(regions), description, [], surface)
