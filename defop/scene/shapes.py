"""Shapes: a mesh of Ω with point handles and sampling regions; the public façade for geometry.

A :class:`Shape` is a mesh of Ω with its point handles p_l (mesh vertices), which of them move
(the variables Q of the handle basis Ψ) and which stay fixed (the bar's clamped end, the blue
handles of Fig. 4), and one sampling region per moving handle (§3.3: where the training
configurations Q_k are drawn).

Shapes come from a polygon (:func:`from_polygon`), an image (:func:`from_image`), a closed triangle
surface (:func:`from_surface`, a tetrahedral mesh in 3D) or the catalogue (:func:`load`, :func:`names`).
The work is done by one module per concern, whose public modules are:

- :mod:`defop.geometry.planar.polygon`: polygon geometry and validation (what Triangle can mesh);
- :mod:`defop.geometry.planar.meshing`: Triangle (:func:`triangulate`);
- :mod:`defop.geometry.planar.outlines`: implicit fields and image silhouettes;
- :mod:`defop.scene.models`: the paper's models (``bar``, ``u_shape``, ``gingerbread``, ``aleph``,
  ``octopus``, ``crab``, ``dino``);
- :mod:`defop.geometry.volumetric`: tetrahedral meshes of solids and closed surfaces;
- :mod:`defop.scene.regions`: sampling regions.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .. import options as opt
from ..geometry.mesh import Mesh
from ..geometry.planar.meshing import MAX_VERTICES, check_n_vertices, triangulate
from ..geometry.planar.outlines import image_outline
from ..geometry.planar.polygon import (
    SCALE_RANGE,
    distance_to_outline,
    points_in_polygon,
    validate_polygon,
)
from ..geometry.volumetric import surface as surfaces
from .models import check_name as _check_name
from .models import default_vertices, model
from .models import dim as _model_dim
from .regions import REGION_KINDS, Disc, Region, as_region

__all__ = [
    "Shape",
    "load",
    "names",
    "from_polygon",
    "from_image",
    "from_surface",
    "default_vertices",
    "REGION_KINDS",
    "MAX_VERTICES",
]


@dataclasses.dataclass(eq=False)
class Shape:
    """A mesh with point handles and sampling regions.

    Attributes
    ----------
    name : str
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices of all handles, moving and fixed.
    moving : (h,) bool numpy array
        Which handles move; Ψ is a function of the moving ones only.
    regions : list of defop.scene.regions.Region
        One sampling region per moving handle, in handle order, centred at its rest position
        (:mod:`defop.scene.regions`; dicts such as ``{"kind": "disc", "radius": r}`` are converted).
    description : str
    outline : list of (k,2) numpy array
        The polygon the mesh was made from (outer loop first); empty in 3D.
    surface : defop.geometry.volumetric.surface.EmbeddedSurface or None
        In 3D, the closed surface the tetrahedra were made from, embedded in them (for drawing).
    """

    name: str
    mesh: Mesh
    handles: np.ndarray
    moving: np.ndarray
    regions: list
    description: str = ""
    outline: list = dataclasses.field(default_factory=list)
    surface: object = None

    def __post_init__(self):
        n = self.mesh.n_vertices
        self.handles = handle_indices(self.handles, n)
        mv = np.asarray(self.moving).ravel()
        if mv.dtype != bool and not (np.issubdtype(mv.dtype, np.number) and np.isin(mv, (0, 1)).all()):
            raise ValueError(f"moving must be one True/False flag per handle, got {self.moving!r}")
        self.moving = mv.astype(bool)
        if len(self.moving) != len(self.handles):
            raise ValueError(f"moving has {len(self.moving)} entries for {len(self.handles)} handles")
        bad = np.flatnonzero((self.handles < 0) | (self.handles >= n))
        if len(bad):
            k = int(bad[0])
            raise ValueError(f"handle {k} is vertex {int(self.handles[k])}, but the mesh has {n} vertices")
        uniq, counts = np.unique(self.handles, return_counts=True)
        if (counts > 1).any():
            raise ValueError(f"vertex {int(uniq[counts > 1][0])} is given as a handle twice")
        if not self.moving.any():
            raise ValueError("a shape needs at least one moving handle")
        if isinstance(self.regions, (dict, Region)):
            self.regions = [self.regions]
        if len(self.regions) != self.n_moving:
            raise ValueError(f"{len(self.regions)} regions for {self.n_moving} moving handles")
        if self.mesh.dim == 3:
            check_handles_span(self.P)
        self.regions = [as_region(r, f"region {i}") for i, r in enumerate(self.regions)]

    @property
    def P(self):
        """(h,d) numpy array: rest positions of all handles."""
        return self.mesh.V[self.handles]

    @property
    def moving_handles(self):
        """(n,) int numpy array: vertex indices of the moving handles."""
        return self.handles[self.moving]

    @property
    def fixed_handles(self):
        """(h-n,) int numpy array: vertex indices of the fixed handles."""
        return self.handles[~self.moving]

    @property
    def P_moving(self):
        """(n,d) numpy array: rest positions p_l of the moving handles."""
        return self.mesh.V[self.moving_handles]

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    def targets(self, Q):
        """Positions of all handles for moved handles Q (fixed ones at rest).

        Parameters
        ----------
        Q : (n,d) numpy array
            Positions of the moving handles.

        Returns
        -------
        T : (h,d) numpy array
        """
        Q = opt.real_array("Q", Q)
        if Q.shape != (self.n_moving, self.mesh.dim):
            n, d = self.n_moving, self.mesh.dim
            raise ValueError(f"Q must have shape ({n}, {d}) for the {n} moving handles, got {Q.shape}")
        if not np.isfinite(Q).all():
            raise ValueError("Q has NaN or infinite entries")
        T = self.P.copy()
        T[self.moving] = Q
        return T

    def __repr__(self):
        return (
            f"Shape({self.name!r}, {self.mesh.n_vertices} vertices, {self.mesh.n_faces} "
            f"{'triangles' if self.mesh.dim == 2 else 'tetrahedra'}, "
            f"{self.n_moving} moving + {len(self.handles) - self.n_moving} fixed handles)"
        )


def check_handles_span(P):
    """Raise ValueError if the handle points P (h,3) lie on one line (or are fewer than 3).

    Point handles fix positions only: a rotation about a line through all of them costs nothing, so
    the variational problem has no unique minimum (its Hessian is singular).
    """
    P = np.asarray(P, float)
    if len(P) >= 3:
        D = P - P[0]
        len2 = D[:, 0] * D[:, 0] + D[:, 1] * D[:, 1] + D[:, 2] * D[:, 2]
        u = D[int(np.argmax(len2))]
        C = np.column_stack(
            [D[:, 1] * u[2] - D[:, 2] * u[1], D[:, 2] * u[0] - D[:, 0] * u[2], D[:, 0] * u[1] - D[:, 1] * u[0]]
        )
        off = np.sqrt((C[:, 0] * C[:, 0] + C[:, 1] * C[:, 1] + C[:, 2] * C[:, 2]) / max(float(len2.max()), 1e-300))
        if off.max() > 1e-9 * np.sqrt(max(float(len2.max()), 1e-300)):
            return
    what = f"the {len(P)} handles lie on one line" if len(P) > 1 else "a single handle"
    raise ValueError(
        f"{what}: in 3D a rotation about a line through them costs nothing (the Hessian is singular); "
        "use at least 3 handles that are not collinear (for example a small patch of handles)"
    )


def handle_vertices(mesh, points, tolerance=0.5):
    """The mesh vertex of each handle point (the nearest one); ValueError for points outside the mesh.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    points : (h,d) numpy array
    tolerance : float
        A point outside the mesh is accepted if its nearest vertex is at most ``tolerance`` × the typical
        edge length away (the snapped boundary of a tetrahedral mesh may pass just inside a surface point).

    Returns
    -------
    idx : (h,) int64 numpy array
    """
    H = opt.real_array("handles", points)
    if H.ndim != 2 or H.shape[1] != mesh.dim or len(H) == 0:
        raise ValueError(f"handles must have shape (h,{mesh.dim}), got {np.shape(points)}")
    if not np.isfinite(H).all():
        raise ValueError("handles have NaN or infinite entries")
    idx, dist = mesh.nearest_vertex(H)
    edge = (6 * float(np.median(mesh.volumes))) ** (1 / 3) if mesh.dim == 3 else np.sqrt(2 * np.median(mesh.volumes))
    outside = ~mesh.contains(H) & (dist > tolerance * edge)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise ValueError(f"handle {k} is outside the mesh (nearest vertex is {dist[k]:.3g} away)")
    uniq, first, counts = np.unique(idx, return_index=True, return_counts=True)
    if (counts > 1).any():
        v = int(uniq[counts > 1][0])
        a, b = np.flatnonzero(idx == v)[:2]
        raise ValueError(
            f"handles {a} and {b} both become vertex {v} (the nearest to each): move them apart or use more vertices"
        )
    return idx


def handle_indices(handles, n):
    """Handle vertex indices as an int64 array: integers (or integral floats), or a boolean mask.

    Parameters
    ----------
    handles : (h,) int array-like or (n,) bool array-like
    n : int
        Number of mesh vertices.

    Returns
    -------
    idx : (h,) int64 numpy array

    Raises
    ------
    ValueError
        A non-integral index (1.7 is not truncated to 1), a mask of the wrong length, or another dtype.
    """
    h = np.asarray(handles)
    if h.dtype == bool:
        if h.shape != (n,):
            raise ValueError(f"a boolean handle mask needs one entry per vertex ({n}), got shape {h.shape}")
        return np.flatnonzero(h).astype(np.int64)
    h = h.ravel()
    if np.issubdtype(h.dtype, np.floating):
        bad = ~np.isfinite(h) | (h != np.round(h))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"handle {k} is {h[k].item()!r}, not an integer vertex index")
    elif not np.issubdtype(h.dtype, np.integer):
        raise ValueError(f"handles must be integer vertex indices or a boolean mask, got dtype {h.dtype}")
    return h.astype(np.int64)


def from_polygon(
    outer,
    holes=(),
    handles=None,
    moving=None,
    regions=None,
    n_vertices=None,
    max_area=None,
    name="polygon",
    description="",
    region_scale=0.25,
):
    """A :class:`Shape` from a polygon with holes and handle points.

    Parameters
    ----------
    outer : (k,2) numpy array
        Outer boundary: a simple polygon (see :func:`defop.geometry.planar.polygon.validate_polygon`).
    holes : list of (l,2) numpy array
        Hole boundaries, strictly inside ``outer``, disjoint and not nested.
    handles : (h,2) numpy array
        Handle positions; each becomes a mesh vertex.
    moving : (h,) bool numpy array, optional
        Which handles move (default: all).
    regions : list of defop.scene.regions.Region or dict, optional
        One per moving handle (default: discs of radius ``region_scale`` × bounding-box diagonal / 2).
    n_vertices : int, optional
        About how many mesh vertices, 3 to ``MAX_VERTICES`` (default 1500 unless ``max_area`` is given).
    max_area : float, optional
        Maximum triangle area instead of ``n_vertices``.
    name, description : str
    region_scale : float

    Returns
    -------
    shape : Shape

    Raises
    ------
    ValueError
        A bad polygon (the message names the vertex, edge or hole), a handle outside the shape, a bad
        vertex count or area.
    """
    if handles is None:
        raise ValueError("from_polygon needs handles: an (h,2) array of handle positions")
    H = np.atleast_2d(opt.real_array("handles", handles))
    if H.ndim != 2 or H.shape[1] != 2 or len(H) == 0:
        raise ValueError(f"handles must have shape (h,2), got {np.shape(handles)}")
    if n_vertices is None and max_area is None:
        n_vertices = 1500
    outer, holes = validate_polygon(outer, holes)
    mesh = triangulate(outer, holes, points=H, n_vertices=n_vertices, max_area=max_area)
    idx, dist = mesh.nearest_vertex(H)
    if not np.all(dist == 0):  # Triangle keeps input points exactly, unless resampling left one outside
        k = int(np.argmax(dist))
        raise ValueError(
            f"handle {k} at ({H[k, 0]:.4g}, {H[k, 1]:.4g}) is not a mesh vertex: it lies outside the outline "
            f"resampled at the mesh spacing (nearest vertex {dist[k]:.3g} away); move it inside or use more vertices"
        )
    moving = np.ones(len(H), bool) if moving is None else moving  # Shape checks the flags
    if regions is None:
        r = region_scale * mesh.bbox_diagonal / 2
        regions = [Disc(r) for _ in range(int(np.count_nonzero(moving)))]
    return Shape(name, mesh, idx, moving, list(regions), description, [outer, *holes])


def from_image(
    image,
    handles=None,
    moving=None,
    regions=None,
    threshold=0.5,
    size=1.0,
    n_vertices=1500,
    name="image",
    n_auto_handles=2,
    foreground="auto",
):
    """A :class:`Shape` from the silhouette of a binary, greyscale, RGB or RGBA image (e.g. a PNG).

    Parameters
    ----------
    image : numpy array or path
        (H,W), (H,W,3) or (H,W,4), bool, integer or float in [0,1]; see
        :func:`defop.geometry.planar.outlines.load_image`.
    handles : (h,2) numpy array, optional
        Handle positions in the output units (the silhouette is scaled so its bounding-box
        diagonal equals ``size``, origin at its bounding-box corner). Default: the
        ``n_auto_handles`` interior points farthest apart.
    moving, regions : see :func:`from_polygon`
    threshold : float
        In (0,1): a pixel is inside when its foreground value exceeds it.
    size : float
    n_vertices : int
    name : str
    n_auto_handles : int
    foreground : str
        ``"auto"`` (default: the alpha channel if it varies, else whatever differs from the
        image border, so a grey, RGB or RGBA copy of the same picture gives the same shape),
        ``"dark"``, ``"light"`` or ``"alpha"``; see :func:`defop.geometry.planar.outlines.foreground`.

    Returns
    -------
    shape : Shape
    """
    size = opt.positive("size", size)  # a negative size mirrored the silhouette
    if not SCALE_RANGE[0] <= size <= SCALE_RANGE[1]:  # 1e300 overflowed into "too thin to place handles"
        raise ValueError(
            f"size must be a positive number in [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}] (the "
            f"coordinate range meshing supports), got {size!r}"
        )
    if handles is None:
        # 0 gave one handle; the candidates are a 60 x 60 grid
        n_auto_handles = opt.integer("n_auto_handles", n_auto_handles, minimum=1, maximum=MAX_AUTO_HANDLES)
    outer, holes = image_outline(image, threshold, foreground_mode=foreground)
    lo = outer.min(axis=0)
    ext = outer.max(axis=0) - lo
    scale = size / np.sqrt(ext[0] * ext[0] + ext[1] * ext[1])
    outer = (outer - lo) * scale
    holes = [(H - lo) * scale for H in holes]
    if handles is None:
        handles = _auto_handles(outer, holes, n_auto_handles)
    return from_polygon(
        outer, holes, handles, moving, regions, n_vertices=n_vertices, name=name, description="silhouette of an image"
    )


#: most handles ``from_image`` places by itself (farthest-point picks on a 60 x 60 grid)
MAX_AUTO_HANDLES = 100


def _auto_handles(outer, holes, k):
    """k well-spread points inside the shape: farthest-point picks on a grid of interior points."""
    lo, hi = outer.min(0), outer.max(0)
    g = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 60), np.linspace(lo[1], hi[1], 60)), -1).reshape(-1, 2)
    loops = [outer, *holes]
    d = distance_to_outline(g, loops)
    ext = hi - lo
    ok = points_in_polygon(g, loops) & (d > 0.02 * np.sqrt(ext[0] * ext[0] + ext[1] * ext[1]))
    cand = g[ok]
    if len(cand) < k:
        raise ValueError("the shape is too thin to place handles automatically; pass handles=")
    pick = [int(np.argmin(cand[:, 0]))]
    for _ in range(k - 1):
        diff = cand[:, None] - cand[pick][None]
        dist = np.min(np.sqrt(diff[..., 0] ** 2 + diff[..., 1] ** 2), axis=1)
        pick.append(int(np.argmax(dist)))
    return cand[pick]


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
    if _model_dim(name) == 3:
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
    _check_name(name)
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
):
    """A 3D :class:`Shape` from a closed triangle surface or a surface file: a tetrahedral mesh of the solid it bounds.

    The solid is meshed by Kuhn cubes (:func:`defop.geometry.volumetric.surface.surface_mesh`: the cubes
    whose centre has winding number ≥ 1/2, boundary snapped toward the surface while every tetrahedron
    keeps a tenth of its volume), the same on every CPU, and the same for every copy of the surface that rounds to
    the same float32 coordinates (an STL and its OBJ). The surface is embedded in the tetrahedra
    (``shape.surface``) so that it can be drawn deformed.

    Parameters
    ----------
    V : (n,3) numpy array, or str or pathlib.Path
        Surface vertices, or the path of a PLY, STL, OBJ or OFF file
        (read by :func:`defop.geometry.volumetric.surface.read_surface`; then F is not given).
    F : (k,3) int numpy array
        Surface triangles: a closed, consistently oriented, manifold surface that does not cross itself
        (inward-facing orientation is flipped).
    handles : (h,3) numpy array
        Handle points inside the solid; each becomes its nearest mesh vertex. At least 3, not all on one
        line (a rotation about that line would be free).
    moving : (h,) bool numpy array, optional
        Which handles move (default: all).
    regions : list of defop.scene.regions.Region or dict, optional
        One per moving handle (default: ``{"kind": "ball", "radius": region_scale × bounding-box diagonal / 2}``).
    n_vertices : int
        About how many tetrahedral mesh vertices, 100 to ``MAX_VERTICES``.
    name, description : str
    region_scale : float
    overlapping_parts : bool
        Accept separate closed parts that cross each other, meshed as their union.
    weld_tolerance : float, optional
        With a path: also merge vertices closer than this fraction of the bounding-box diagonal (a surface
        whose copies of one vertex differ slightly reads as open without it).

    Returns
    -------
    shape : Shape

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
        raise ValueError("from_surface needs handles: an (h,3) array of handle positions inside the solid")
    n_vertices = check_n_vertices(n_vertices)
    if n_vertices < 100:
        raise ValueError(f"n_vertices must be an integer >= 100, got {n_vertices!r}")
    V, F = surfaces.check_surface(V, F, overlapping_parts=overlapping_parts)
    mesh = surfaces.surface_mesh(V, F, n_vertices, checked=True)
    idx = handle_vertices(mesh, handles)
    moving = np.ones(len(idx), bool) if moving is None else moving  # Shape checks the flags
    if regions is None:
        r = region_scale * mesh.bbox_diagonal / 2
        regions = [{"kind": "ball", "radius": r} for _ in range(int(np.count_nonzero(moving)))]
    surface = surfaces.EmbeddedSurface.embed(mesh, V, F)
    return Shape(name, mesh, idx, moving, list(regions), description, [], surface)
