"""Planar shapes from a polygon with holes (:func:`from_polygon`) or from the silhouette of an image
(:func:`from_image`); both place handles by themselves when none are given (:mod:`defop.scene.auto_handles`).
And the map from such a shape back to its picture's pixels (:func:`image_frame`)."""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from ..geometry.planar.meshing import triangulate
from ..geometry.planar.outlines import image_outline, load_image
from ..geometry.planar.polygon import SCALE_RANGE, distance_to_outline, points_in_polygon, validate_polygon
from .auto_handles import automatic_handles
from .regions import Disc
from .shape import Shape

__all__ = ["from_polygon", "from_image", "image_frame", "MAX_AUTO_HANDLES", "auto_handles"]

#: most handles ``from_polygon`` and ``from_image`` place by themselves
MAX_AUTO_HANDLES = 100


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
    n_auto_handles=2,
):
    """A :class:`Shape` from a polygon with holes and handle points.

    Parameters
    ----------
    outer : (k,2) numpy array
        Outer boundary: a simple polygon (see :func:`defop.geometry.planar.polygon.validate_polygon`).
    holes : list of (l,2) numpy array
        Hole boundaries, strictly inside ``outer``, disjoint and not nested.
    handles : (h,2) numpy array, optional
        Handle positions; each becomes a mesh vertex. Default: the ``n_auto_handles`` extremities of the
        mesh's boundary (:func:`defop.scene.auto_handles.extremities`: the boundary vertex farthest from the
        centroid, then farthest-point sampling).
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
    n_auto_handles : int
        How many handles to place without ``handles``, 1 to :data:`MAX_AUTO_HANDLES`.

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
        n_auto_handles = opt.integer("n_auto_handles", n_auto_handles, minimum=1, maximum=MAX_AUTO_HANDLES)
    else:
        H = np.atleast_2d(opt.real_array("handles", handles))
        if H.ndim != 2 or H.shape[1] != 2 or len(H) == 0:
            raise ValueError(f"handles must have shape (h,2), got {np.shape(handles)}")
    if n_vertices is None and max_area is None:
        n_vertices = 1500
    outer, holes = validate_polygon(outer, holes)
    if handles is None:
        mesh = triangulate(outer, holes, n_vertices=n_vertices, max_area=max_area)
        idx = automatic_handles(mesh, n_auto_handles)[1]
    else:
        mesh = triangulate(outer, holes, points=H, n_vertices=n_vertices, max_area=max_area)
        idx = _exact_vertices(mesh, H)
    moving = np.ones(len(idx), bool) if moving is None else moving  # Shape checks the flags
    if regions is None:
        r = region_scale * mesh.bbox_diagonal / 2
        regions = [Disc(r) for _ in range(int(np.count_nonzero(moving)))]
    return Shape(name, mesh, idx, moving, list(regions), description, [outer, *holes])


def _exact_vertices(mesh, H):
    """The mesh vertex at each handle point H (h,2); ValueError for a point that is not exactly a vertex."""
    idx, dist = mesh.nearest_vertex(H)
    if not np.all(dist == 0):  # Triangle keeps input points exactly, unless resampling left one outside
        k = int(np.argmax(dist))
        raise ValueError(
            f"handle {k} at ({H[k, 0]:.4g}, {H[k, 1]:.4g}) is not a mesh vertex: it lies outside the outline "
            f"resampled at the mesh spacing (nearest vertex {dist[k]:.3g} away); move it inside or use more vertices"
        )
    return idx


def from_image(
    image,
    handles=None,
    moving=None,
    regions=None,
    threshold=None,
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
        ``n_auto_handles`` extremities of the mesh's boundary, as in :func:`from_polygon`.
    moving, regions : see :func:`from_polygon`
    threshold : float or None
        None (default): the automatic rule, one for every picture (Otsu's split of the alpha channel when it
        varies, else of the colour distance from the picture's border; see
        :func:`defop.geometry.planar.silhouette.silhouette`): a shape of any colour on any other colour keeps its
        area. A number in (0,1): a pixel is inside when its foreground value exceeds it.
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
        Its ``outline`` is the silhouette in the output units; :func:`image_frame` maps it back to the pixels
        (``to_html(op, path, shape=shape, image=picture)`` does that itself).

    Warns
    -----
    UserWarning
        When the picture's foreground has separate regions: all but the largest are dropped (the message gives
        the share of the foreground's area lost and names ``threshold=``).
    """
    size = opt.positive("size", size)  # a negative size mirrored the silhouette
    if not SCALE_RANGE[0] <= size <= SCALE_RANGE[1]:  # 1e300 overflowed into "too thin to place handles"
        raise ValueError(
            f"size must be a positive number in [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}] (the "
            f"coordinate range meshing supports), got {size!r}"
        )
    if handles is None:
        # 0 gave one handle; checked before the image is read
        n_auto_handles = opt.integer("n_auto_handles", n_auto_handles, minimum=1, maximum=MAX_AUTO_HANDLES)
    outer, holes = image_outline(image, threshold, foreground_mode=foreground)
    lo = outer.min(axis=0)
    ext = outer.max(axis=0) - lo
    scale = size / np.sqrt(ext[0] * ext[0] + ext[1] * ext[1])
    outer = (outer - lo) * scale
    holes = [(H - lo) * scale for H in holes]
    return from_polygon(
        outer,
        holes,
        handles,
        moving,
        regions,
        n_vertices=n_vertices,
        name=name,
        description="silhouette of an image",
        n_auto_handles=n_auto_handles,
    )


def auto_handles(outer, holes, k):
    """k well-spread points inside the shape: farthest-point picks on a grid of interior points.

    Deprecated: :func:`from_polygon` and :func:`from_image` place their handles by
    :func:`defop.scene.auto_handles.extremities`, the rule of 3D shapes too.
    """
    warnings.warn(
        "planar_shapes.auto_handles is deprecated: automatic handles are defop.scene.auto_handles.extremities",
        DeprecationWarning,
        stacklevel=2,
    )
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


def image_frame(image, shape, threshold=None, foreground="auto"):
    """The map from the coordinates of a shape made by :func:`from_image` to the pixels of its picture.

    The picture's silhouette is found again, by the same rule (pass the ``threshold`` and ``foreground`` that
    ``from_image`` was given), and matched to ``shape.outline``: ``from_image`` put the silhouette's bounding box
    at the origin, y up, scaled to a diagonal of ``size``. The match is checked point by point, so a picture or a
    rule other than the shape's is an error, not a shifted picture.

    Parameters
    ----------
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path
        The picture ``from_image`` was given (see :func:`defop.geometry.planar.outlines.load_image`).
    shape : Shape
        The 2D shape ``from_image(image, ...)`` made (or one with its mesh and outline).
    threshold, foreground :
        As given to :func:`from_image`.

    Returns
    -------
    to_pixels : callable
        ``to_pixels((k,2) shape coordinates) -> (k,2) pixels``: x = column, y = row (down), pixel centres at
        integers; what ``image_frame=`` of :func:`defop.editor.export.to_html` and
        :class:`defop.editor.browser.BrowserEditor` take.

    Raises
    ------
    ValueError
        ``shape`` not a 2D Shape with an outline, a bad picture, or a silhouette that is not the shape's outline
        (naming ``threshold=`` and ``foreground=``).
    """
    from scipy.spatial import cKDTree

    if not isinstance(shape, Shape) or shape.mesh.dim != 2 or not len(shape.outline):
        raise ValueError(f"shape must be a 2D Shape made by from_image, got {type(shape).__name__}")
    img = load_image(image)
    with warnings.catch_warnings():  # from_image has already said what it dropped
        warnings.simplefilter("ignore", UserWarning)
        outer, _ = image_outline(img, threshold, foreground_mode=foreground)
    mine = np.asarray(shape.outline[0], dtype=float)
    lo, mine_lo = outer.min(axis=0), mine.min(axis=0)
    diagonal = float(np.hypot(*np.ptp(mine, axis=0)))
    scale = diagonal / float(np.hypot(*np.ptp(outer, axis=0)))
    mapped = (outer - lo) * scale + mine_lo
    gap = max(cKDTree(mapped).query(mine)[0].max(), cKDTree(mine).query(mapped)[0].max())
    if gap > 1e-9 * diagonal:
        raise ValueError(
            f"the picture's silhouette is not the outline of shape {shape.name!r} (they differ by {gap / scale:.3g} "
            f"pixels), found with threshold={threshold!r}, foreground={foreground!r}: the shape was made from "
            f"another picture, or by from_image with other threshold= or foreground=; give those to "
            f"dop.shapes.image_frame(picture, shape, threshold=..., foreground=...) and pass what it returns as "
            f"image_frame= (or the rest vertices in pixels, for a picture in another frame)"
        )
    H = img.shape[0]

    def to_pixels(x):
        up = (np.asarray(x, dtype=float) - mine_lo) / scale + lo
        return np.column_stack([up[:, 0], (H - 1) - up[:, 1]])

    return to_pixels
