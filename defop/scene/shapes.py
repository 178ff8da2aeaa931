"""Shapes: a mesh of Ω with point handles and sampling regions; the public façade for geometry.

A :class:`Shape` is a mesh of Ω with its point handles p_l (mesh vertices), which of them move
(the variables Q of the handle basis Ψ) and which stay fixed (the bar's clamped end, the blue
handles of Fig. 4), and one sampling region per moving handle (§3.3: where the training
configurations Q_k are drawn).

Shapes come from a polygon (:func:`from_polygon`), an image (:func:`from_image`) or the paper's
catalogue (:func:`load`, :func:`names`). The work is done by one module per concern, whose public
modules are:

- :mod:`defop.geometry.planar.polygon`: polygon geometry and validation (what Triangle can mesh);
- :mod:`defop.geometry.planar.meshing`: Triangle (:func:`triangulate`);
- :mod:`defop.geometry.planar.outlines`: implicit fields and image silhouettes;
- :mod:`defop.scene.models`: the paper's models (``bar``, ``u_shape``, ``gingerbread``, ``aleph``,
  ``octopus``, ``crab``, ``dino``);
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
from .models import check_name as _check_name
from .models import default_vertices, model
from .regions import REGION_KINDS, Disc, Region, as_region

__all__ = [
    "Shape",
    "load",
    "names",
    "from_polygon",
    "from_image",
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
        The polygon the mesh was made from (outer loop first).
    """

    name: str
    mesh: Mesh
    handles: np.ndarray
    moving: np.ndarray
    regions: list
    description: str = ""
    outline: list = dataclasses.field(default_factory=list)

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
        self.regions = [as_region(r, f"region {i}") for i, r in enumerate(self.regions)]

    @property
    def P(self):
        """(h,2) numpy array: rest positions of all handles."""
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
        """(n,2) numpy array: rest positions p_l of the moving handles."""
        return self.mesh.V[self.moving_handles]

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    def targets(self, Q):
        """Positions of all handles for moved handles Q (fixed ones at rest).

        Parameters
        ----------
        Q : (n,2) numpy array
            Positions of the moving handles.

        Returns
        -------
        T : (h,2) numpy array
        """
        Q = opt.real_array("Q", Q)
        if Q.shape != (self.n_moving, 2):
            n = self.n_moving
            raise ValueError(f"Q must have shape ({n}, 2) for the {n} moving handles, got {Q.shape}")
        if not np.isfinite(Q).all():
            raise ValueError("Q has NaN or infinite entries")
        T = self.P.copy()
        T[self.moving] = Q
        return T

    def __repr__(self):
        return (
            f"Shape({self.name!r}, {self.mesh.n_vertices} vertices, {self.mesh.n_faces} triangles, "
            f"{self.n_moving} moving + {len(self.handles) - self.n_moving} fixed handles)"
        )


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
        raise ValueError(f"size must be a positive number in [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}] (the "
                         f"coordinate range meshing supports), got {size!r}")
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


def names():
    """Names of the built-in shapes.

    Returns
    -------
    names : list of str
    """
    from .models import CATALOGUE

    return list(CATALOGUE)


@functools.lru_cache(maxsize=32)
def _load(name, n_vertices):
    m = model(name)
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
    """One of the paper's models as a :class:`Shape`.

    Parameters
    ----------
    name : str
        One of :func:`names`.
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
    )
