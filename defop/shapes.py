"""Shapes: outlines → Triangle meshes, and the paper's models with default handles.

A :class:`Shape` is a mesh of Ω with its point handles p_l (mesh vertices), which of them move
(the variables Q of the handle basis Ψ) and which stay fixed (the bar's clamped end, the blue
handles of Fig. 4), and one sampling region per moving handle (§3.3: where the training
configurations Q_k are drawn).

The named models (``names()``) are procedural outlines that look like the paper's models:
``bar`` (Fig. 3, 7), ``u_shape`` (Fig. 4), ``gingerbread`` (Fig. 6), ``aleph`` (Fig. 8, 9; the
letter א of DejaVu Sans through matplotlib's ``TextPath``), ``octopus`` (Fig. 1), ``crab``
(Fig. 2) and ``dino`` (Table 1). Organic outlines are unions of tapered capsules and ellipses,
extracted as a level set with contourpy and meshed by Shewchuk's Triangle.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np

from .mesh import Mesh

REGION_KINDS = ("disc", "ellipse", "circle", "gaussian", "voronoi", "mixture")


# ----------------------------------------------------------------------------------------------
# polygons
# ----------------------------------------------------------------------------------------------
def polygon_area(poly):
    """Signed area of a closed polygon (shoelace; > 0 when counter-clockwise).

    Parameters
    ----------
    poly : (k,2) numpy array

    Returns
    -------
    area : float
    """
    x, y = np.asarray(poly, float).T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _check_polygon(poly, name):
    P = np.asarray(poly, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2:
        raise ValueError(f"{name} must have shape (k,2), got {P.shape}")
    if not np.isfinite(P).all():
        first = int(np.argwhere(~np.isfinite(P))[0, 0])
        raise ValueError(f"{name} has NaN or infinite coordinates (first at point {first})")
    if len(P) > 1 and np.allclose(P[0], P[-1]):
        P = P[:-1]  # closed explicitly
    if len(P) < 3:
        raise ValueError(f"{name} has {len(P)} points; a polygon needs at least 3")
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    if np.any(seg == 0):
        raise ValueError(f"{name} repeats point {int(np.flatnonzero(seg == 0)[0])}")
    return P


def _segments_cross(A0, A1, B0, B1):
    """Proper crossings between segments A[i] and B[j]: (len(A), len(B)) bool."""

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    a0, a1 = A0[:, None], A1[:, None]
    b0, b1 = B0[None], B1[None]
    d1, d2 = orient(a0, a1, b0), orient(a0, a1, b1)
    d3, d4 = orient(b0, b1, a0), orient(b0, b1, a1)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def self_intersections(loops):
    """Pairs of crossing edges among closed polygons (edges i of loop a and j of loop b).

    Parameters
    ----------
    loops : list of (k,2) numpy array

    Returns
    -------
    crossings : list of ((int, int), (int, int))
        ``((loop_a, edge_i), (loop_b, edge_j))``, empty when the polygons are simple and disjoint.
    """
    out = []
    edges = [(P, np.roll(P, -1, axis=0)) for P in loops]
    for a, (A0, A1) in enumerate(edges):
        for b in range(a, len(edges)):
            B0, B1 = edges[b]
            for start in range(0, len(A0), 512):
                X = _segments_cross(A0[start : start + 512], A1[start : start + 512], B0, B1)
                for i, j in np.argwhere(X):
                    i = int(i) + start
                    if a == b and (j <= i):
                        continue
                    out.append(((a, i), (b, int(j))))
    return out


def points_in_polygon(points, loops):
    """Even-odd point-in-polygon test against an outline with holes.

    Parameters
    ----------
    points : (k,2) numpy array
    loops : list of (l,2) numpy array
        The outer loop and the holes.

    Returns
    -------
    inside : (k,) bool numpy array
    """
    pts = np.atleast_2d(np.asarray(points, float))
    inside = np.zeros(len(pts), bool)
    for P in loops:
        Q = np.roll(P, -1, axis=0)
        x, y = pts[:, 0:1], pts[:, 1:2]
        cond = (P[None, :, 1] > y) != (Q[None, :, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = P[None, :, 0] + (y - P[None, :, 1]) * (Q[None, :, 0] - P[None, :, 0]) / (Q[None, :, 1] - P[None, :, 1])
        inside ^= (np.sum(cond & (x < xc), axis=1) % 2).astype(bool)
    return inside


def distance_to_outline(points, loops):
    """Distance of each point to the nearest outline edge.

    Parameters
    ----------
    points : (k,2) numpy array
    loops : list of (l,2) numpy array

    Returns
    -------
    dist : (k,) numpy array
    """
    pts = np.atleast_2d(np.asarray(points, float))
    best = np.full(len(pts), np.inf)
    for P in loops:
        Q = np.roll(P, -1, axis=0)
        d = Q - P
        t = np.clip(np.einsum("kjc,jc->kj", pts[:, None] - P[None], d) / np.einsum("jc,jc->j", d, d), 0, 1)
        proj = P[None] + t[..., None] * d[None]
        best = np.minimum(best, np.linalg.norm(pts[:, None] - proj, axis=-1).min(axis=1))
    return best


def resample(loop, h, corner_angle=20.0):
    """Resample a closed polyline by arc length with spacing about ``h``, keeping its corners.

    Vertices where the outline turns by more than ``corner_angle`` degrees are kept exactly
    (so a polygon's area is preserved); the pieces between them are resampled uniformly.

    Parameters
    ----------
    loop : (k,2) numpy array
    h : float
    corner_angle : float

    Returns
    -------
    out : (l,2) numpy array, l >= 8 unless the loop has fewer corners than that
    """
    P = np.asarray(loop, float)
    e_in = P - np.roll(P, 1, axis=0)
    e_out = np.roll(P, -1, axis=0) - P
    cosang = np.einsum("ij,ij->i", e_in, e_out) / (np.linalg.norm(e_in, axis=1) * np.linalg.norm(e_out, axis=1))
    corners = np.flatnonzero(cosang < np.cos(np.radians(corner_angle)))
    if len(corners) == 0:
        Pc = np.vstack([P, P[:1]])
        s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(Pc, axis=0), axis=1))])
        n = max(8, int(round(s[-1] / h)))
        t = np.linspace(0, s[-1], n, endpoint=False)
        return np.column_stack([np.interp(t, s, Pc[:, 0]), np.interp(t, s, Pc[:, 1])])
    out = []
    for a, b in zip(corners, np.roll(corners, -1)):
        idx = np.arange(a, b + 1) if b > a else np.concatenate([np.arange(a, len(P)), np.arange(0, b + 1)])
        piece = P[idx]
        s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(piece, axis=0), axis=1))])
        n = max(1, int(round(s[-1] / h)))
        t = np.linspace(0, s[-1], n, endpoint=False)
        out.append(np.column_stack([np.interp(t, s, piece[:, 0]), np.interp(t, s, piece[:, 1])]))
    return np.vstack(out)


# ----------------------------------------------------------------------------------------------
# triangulation
# ----------------------------------------------------------------------------------------------
def _triangle(outer, holes, points, max_area):
    import triangle as tr

    loops = [outer, *holes]
    verts = np.vstack(loops + ([points] if len(points) else []))
    segs, start = [], 0
    for L in loops:
        k = len(L)
        segs.append(np.column_stack([np.arange(k), (np.arange(k) + 1) % k]) + start)
        start += k
    data = {"vertices": verts, "segments": np.vstack(segs)}
    if holes:
        data["holes"] = np.array([_interior_point(H) for H in holes])
    flags = "pqQ" + (f"a{max_area:.10f}" if max_area else "")
    out = tr.triangulate(data, flags)
    # a vertex in a single triangle (an "ear" at a sharp corner) is badly constrained by FEM energies:
    # split such triangles at their centroid
    for _ in range(3):
        V, F = out["vertices"], out["triangles"]
        lone = np.flatnonzero(np.bincount(F.ravel(), minlength=len(V)) == 1)
        if not len(lone):
            break
        ears = F[np.isin(F, lone).any(axis=1)]
        data["vertices"] = np.vstack([data["vertices"], V[ears].mean(axis=1)])
        out = tr.triangulate(data, flags)
    return out["vertices"], out["triangles"]


def _interior_point(loop):
    """A point strictly inside a simple polygon (centroid if inside, else a probe near an ear)."""
    c = loop.mean(axis=0)
    if points_in_polygon(c[None], [loop])[0]:
        return c
    # try midpoints between the first vertex and every other vertex
    for k in range(2, len(loop)):
        m = 0.5 * (loop[0] + loop[k])
        if points_in_polygon(m[None], [loop])[0]:
            return m
    raise ValueError("could not find a point inside a hole")


def triangulate(outer, holes=(), points=None, max_area=None, n_vertices=None, h=None):
    """Mesh a polygon with holes by Triangle (quality, conforming), with given points as vertices.

    Parameters
    ----------
    outer : (k,2) numpy array
        The outer boundary (either orientation).
    holes : list of (l,2) numpy array
        Hole boundaries.
    points : (p,2) numpy array, optional
        Points that must be mesh vertices (handles); find their indices with
        ``mesh.nearest_vertex(points)`` (distance 0).
    max_area : float, optional
        Maximum triangle area.
    n_vertices : int, optional
        Aim at about this many vertices (overrides ``max_area``; two refinement passes).
    h : float, optional
        Resample the outline with spacing ``h`` first (default: keep it).

    Returns
    -------
    mesh : defop.mesh.Mesh

    Raises
    ------
    ValueError
        Fewer than 3 points, NaN, a self-intersecting polygon, or points outside the polygon.
    """
    outer = _check_polygon(outer, "outer polygon")
    holes = [_check_polygon(H, f"hole {i}") for i, H in enumerate(holes)]
    loops = [outer, *holes]
    crossings = self_intersections(loops)
    if crossings:
        (a, i), (b, j) = crossings[0]
        what = ["outer polygon"] + [f"hole {k}" for k in range(len(holes))]
        raise ValueError(
            f"the polygon is self-intersecting: edge {i} of the {what[a]} crosses edge {j} of the {what[b]} "
            f"({len(crossings)} crossing(s) in all)"
        )
    for L, what in zip(loops, ["outer polygon"] + [f"hole {k}" for k in range(len(holes))]):
        if abs(polygon_area(L)) < 1e-14 * max(1.0, np.ptp(L) ** 2):
            raise ValueError(f"the {what} has zero area")
    points = np.zeros((0, 2)) if points is None else np.atleast_2d(np.asarray(points, float))
    if len(points):
        if not np.isfinite(points).all():
            raise ValueError("points have NaN or infinite coordinates")
        inside = points_in_polygon(points, loops)
        if not inside.all():
            k = int(np.flatnonzero(~inside)[0])
            d = distance_to_outline(points[k : k + 1], loops)[0]
            raise ValueError(
                f"handle {k} at ({points[k, 0]:.4g}, {points[k, 1]:.4g}) is outside the shape "
                f"(nearest boundary point is {d:.3g} away)"
            )
    area = abs(polygon_area(outer)) - sum(abs(polygon_area(H)) for H in holes)
    if n_vertices is not None:
        max_area = 1.6 * area / n_vertices
    if h is None and max_area is not None:
        h = np.sqrt(4 / np.sqrt(3) * max_area)
    if h is not None:
        loops = [resample(L, h) for L in loops]
    V, F = _triangle(loops[0], loops[1:], points, max_area)
    if n_vertices is not None:
        for _ in range(2):
            ratio = len(V) / n_vertices
            if abs(ratio - 1) < 0.04:
                break
            max_area *= ratio
            h = np.sqrt(4 / np.sqrt(3) * max_area)
            rs = [resample(L, h) for L in [outer, *holes]]
            V, F = _triangle(rs[0], rs[1:], points, max_area)
    return Mesh(V, F)


# ----------------------------------------------------------------------------------------------
# Shape
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(eq=False)
class Shape:
    """A mesh with point handles and sampling regions.

    Attributes
    ----------
    name : str
    mesh : defop.mesh.Mesh
    handles : (h,) int numpy array
        Vertex indices of all handles, moving and fixed.
    moving : (h,) bool numpy array
        Which handles move; Ψ is a function of the moving ones only.
    regions : list of dict
        One sampling region per moving handle, in handle order, centred at its rest position:
        ``{"kind": "disc", "radius": r}``, ``{"kind": "ellipse", "axes": [a_x, a_y]}`` (uniform in an
        axis-aligned ellipse), ``{"kind": "circle", "radius": r}``,
        ``{"kind": "gaussian", "sigma": s}``, ``{"kind": "voronoi", "radius": r}`` (the Voronoi
        cell of p_l among the moving handles, clipped to a disc), or
        ``{"kind": "mixture", "components": [...], "weights": [...]}``.
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
        self.handles = np.asarray(self.handles, dtype=np.int64).ravel()
        self.moving = np.asarray(self.moving, dtype=bool).ravel()
        n = self.mesh.n_vertices
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
        if len(self.regions) != self.n_moving:
            raise ValueError(f"{len(self.regions)} regions for {self.n_moving} moving handles")
        for i, r in enumerate(self.regions):
            check_region(r, f"region {i}")

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
        Q = np.asarray(Q, dtype=float)
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


def check_region(region, name="region"):
    """Validate a sampling-region dict; raise ValueError naming the problem."""
    if not isinstance(region, dict) or "kind" not in region:
        raise ValueError(f"{name} must be a dict with a 'kind' in {REGION_KINDS}, got {region!r}")
    kind = region["kind"]
    need = {"disc": "radius", "circle": "radius", "gaussian": "sigma", "voronoi": "radius"}
    if kind in need:
        v = region.get(need[kind])
        if v is None or not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name} ({kind}) needs a positive '{need[kind]}', got {v!r}")
    elif kind == "ellipse":
        ax = np.asarray(region.get("axes", ()), float)
        if ax.shape != (2,) or not np.all(np.isfinite(ax)) or np.any(ax <= 0):
            raise ValueError(f"{name} (ellipse) needs two positive 'axes' [a_x, a_y], got {region.get('axes')!r}")
    elif kind == "mixture":
        comps, w = region.get("components"), region.get("weights")
        if not comps or w is None or len(w) != len(comps) or np.any(np.asarray(w) < 0) or np.sum(w) <= 0:
            raise ValueError(f"{name} (mixture) needs components and as many non-negative weights")
        for i, c in enumerate(comps):
            check_region(c, f"{name} component {i}")
    else:
        raise ValueError(f"{name} has unknown kind {kind!r}; known kinds: {', '.join(REGION_KINDS)}")


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
        Outer boundary.
    holes : list of (l,2) numpy array
        Hole boundaries.
    handles : (h,2) numpy array
        Handle positions; each becomes a mesh vertex.
    moving : (h,) bool numpy array, optional
        Which handles move (default: all).
    regions : list of dict, optional
        One per moving handle (default: discs of radius ``region_scale`` × bounding-box diagonal / 2).
    n_vertices : int, optional
        About how many mesh vertices (default 1500 unless ``max_area`` is given).
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
        Bad polygon (fewer than 3 points, NaN, self-intersecting), handle outside the shape.
    """
    if handles is None:
        raise ValueError("from_polygon needs handles: an (h,2) array of handle positions")
    H = np.atleast_2d(np.asarray(handles, dtype=float))
    if H.ndim != 2 or H.shape[1] != 2 or len(H) == 0:
        raise ValueError(f"handles must have shape (h,2), got {np.shape(handles)}")
    if n_vertices is None and max_area is None:
        n_vertices = 1500
    mesh = triangulate(outer, holes, points=H, n_vertices=n_vertices, max_area=max_area)
    idx, dist = mesh.nearest_vertex(H)
    assert np.all(dist < 1e-9), "Triangle moved a handle vertex"
    moving = np.ones(len(H), bool) if moving is None else np.asarray(moving, bool)
    if regions is None:
        r = region_scale * mesh.bbox_diagonal / 2
        regions = [{"kind": "disc", "radius": r} for _ in range(int(moving.sum()))]
    loops = [_check_polygon(outer, "outer polygon")] + [_check_polygon(h, "hole") for h in holes]
    return Shape(name, mesh, idx, moving, list(regions), description, loops)


# ----------------------------------------------------------------------------------------------
# images and implicit outlines
# ----------------------------------------------------------------------------------------------
def _level_set_loops(Z, x, y, level):
    """Closed contour loops of Z = level (Z > level is inside), outer loops CCW, holes CW."""
    import contourpy

    gen = contourpy.contour_generator(x, y, Z, line_type=contourpy.LineType.Separate)
    loops = []
    for L in gen.lines(level):
        L = np.asarray(L)
        if len(L) > 1 and np.allclose(L[0], L[-1]):
            L = L[:-1]
        if len(L) >= 3 and abs(polygon_area(L)) > 0:
            loops.append(L)
    return loops


def _outline_from_field(Z, x, y, level=0.0, min_area_frac=1e-3):
    """The largest component of {Z > level} as (outer, holes)."""
    loops = _level_set_loops(Z, x, y, level)
    if not loops:
        return None, []
    areas = np.array([abs(polygon_area(L)) for L in loops])
    order = np.argsort(-areas)
    outer = loops[order[0]]
    holes = []
    for k in order[1:]:
        L = loops[k]
        if areas[k] < min_area_frac * areas[order[0]]:
            continue
        if points_in_polygon(L[:1], [outer])[0]:
            # a loop inside the outer one is a hole unless it sits inside another hole (an island)
            if not any(points_in_polygon(L[:1], [h])[0] for h in holes):
                holes.append(L)
    return outer, holes


def image_outline(image, threshold=0.5, smooth=1.0):
    """Silhouette of an image as polygons (largest connected component, with its holes).

    Parameters
    ----------
    image : (H,W) or (H,W,3|4) numpy array, or a path to an image file
        Foreground is where the value (alpha channel for RGBA; darkness for RGB) exceeds
        ``threshold`` (values are scaled to [0,1]).
    threshold : float
    smooth : float
        Gaussian blur (pixels) before extracting the contour, to remove pixel stairs.

    Returns
    -------
    outer : (k,2) numpy array
        In pixel units, y up, origin at the bottom-left.
    holes : list of (l,2) numpy array

    Raises
    ------
    ValueError
        An image with no foreground.
    """
    from scipy.ndimage import gaussian_filter

    img = _load_image(image)
    if img.ndim == 3:
        if img.shape[2] == 4 and np.ptp(img[..., 3]) > 0:
            fg = img[..., 3]
        else:
            fg = 1.0 - img[..., :3].mean(axis=2)  # dark on light
    else:
        fg = img
    fg = np.asarray(fg, float)
    if fg.max() > 1.0:
        fg = fg / 255.0
    mask = fg > threshold
    if not mask.any():
        raise ValueError(f"the image has no foreground (no pixel above threshold {threshold})")
    if mask.all():
        raise ValueError("the image is all foreground; the silhouette needs a background around it")
    Z = np.pad(mask.astype(float), 2)
    if smooth:
        Z = gaussian_filter(Z, smooth)
    Z = Z[::-1]  # y up
    h, w = Z.shape
    x = np.arange(w) - 2.0
    y = np.arange(h) - 2.0
    outer, holes = _outline_from_field(Z, x, y, 0.5)
    if outer is None:
        raise ValueError("the image has no foreground region large enough to mesh")
    return outer, holes


def _load_image(image):
    if isinstance(image, (str, Path)):
        path = Path(image)
        if not path.exists():
            raise ValueError(f"no such image file: {path}")
        from matplotlib.image import imread  # reading a file, not plotting

        return np.asarray(imread(path))
    return np.asarray(image)


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
):
    """A :class:`Shape` from the silhouette of a binary, greyscale or RGBA image (e.g. a PNG).

    Parameters
    ----------
    image : numpy array or path
        See :func:`image_outline`.
    handles : (h,2) numpy array, optional
        Handle positions in the output units (the silhouette is scaled so its bounding-box
        diagonal equals ``size``, origin at its bounding-box corner). Default: the
        ``n_auto_handles`` outline points farthest apart, moved slightly inside.
    moving, regions : see :func:`from_polygon`
    threshold : float
    size : float
    n_vertices : int
    name : str
    n_auto_handles : int

    Returns
    -------
    shape : Shape
    """
    outer, holes = image_outline(image, threshold)
    lo = outer.min(axis=0)
    scale = size / np.linalg.norm(outer.max(axis=0) - lo)
    outer = (outer - lo) * scale
    holes = [(H - lo) * scale for H in holes]
    if handles is None:
        handles = _auto_handles(outer, holes, n_auto_handles)
    return from_polygon(
        outer, holes, handles, moving, regions, n_vertices=n_vertices, name=name, description="silhouette of an image"
    )


def _auto_handles(outer, holes, k):
    """k well-spread points inside the shape: farthest-point picks on a grid of interior points."""
    lo, hi = outer.min(0), outer.max(0)
    g = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 60), np.linspace(lo[1], hi[1], 60)), -1).reshape(-1, 2)
    loops = [outer, *holes]
    d = distance_to_outline(g, loops)
    ok = points_in_polygon(g, loops) & (d > 0.02 * np.linalg.norm(hi - lo))
    cand = g[ok]
    if len(cand) < k:
        raise ValueError("the shape is too thin to place handles automatically; pass handles=")
    pick = [int(np.argmin(cand[:, 0]))]
    for _ in range(k - 1):
        dist = np.min(np.linalg.norm(cand[:, None] - cand[pick][None], axis=-1), axis=1)
        pick.append(int(np.argmax(dist)))
    return cand[pick]


def implicit_outline(field, bbox, resolution=400):
    """Outline of {field > 0} sampled on a grid (for procedural shapes).

    Parameters
    ----------
    field : callable
        ``field(P (k,2)) -> (k,)``, positive inside.
    bbox : (2,2) array-like
        ``[[xmin, ymin], [xmax, ymax]]``.
    resolution : int
        Grid points along the longer side.

    Returns
    -------
    outer : (k,2) numpy array
    holes : list of (l,2) numpy array
    """
    (x0, y0), (x1, y1) = np.asarray(bbox, float)
    s = max(x1 - x0, y1 - y0) / resolution
    x = np.arange(x0, x1 + s, s)
    y = np.arange(y0, y1 + s, s)
    X, Y = np.meshgrid(x, y)
    Z = field(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
    outer, holes = _outline_from_field(Z, x, y, 0.0)
    return outer, holes


# primitives for implicit shapes: signed "inside-ness" (positive inside), combined by max (union)
def capsule(a, b, ra, rb=None):
    """Tapered capsule from a (radius ra) to b (radius rb): field = radius(t) - distance."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    rb = ra if rb is None else rb

    def f(P):
        d = b - a
        t = np.clip((P - a) @ d / (d @ d), 0, 1)
        return ra + (rb - ra) * t - np.linalg.norm(P - (a + t[:, None] * d), axis=1)

    return f


def ellipse(c, rx, ry, angle=0.0):
    """Ellipse field: scaled so that it behaves like a distance near the boundary."""
    c = np.asarray(c, float)
    ca, sa = np.cos(angle), np.sin(angle)

    def f(P):
        u = (P - c) @ np.array([[ca, -sa], [sa, ca]])
        return min(rx, ry) * (1 - np.sqrt((u[:, 0] / rx) ** 2 + (u[:, 1] / ry) ** 2))

    return f


def chain(points, r0, r1):
    """A tapered tube along a polyline (union of capsules), radius r0 → r1."""
    pts = np.asarray(points, float)
    L = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    r = r0 + (r1 - r0) * L / L[-1]
    parts = [capsule(pts[i], pts[i + 1], r[i], r[i + 1]) for i in range(len(pts) - 1)]
    return union(*parts)


def union(*fields):
    def f(P):
        return np.max([g(P) for g in fields], axis=0)

    return f


def subtract(f, g):
    def h(P):
        return np.minimum(f(P), -g(P))

    return h


# ----------------------------------------------------------------------------------------------
# the paper's models
# ----------------------------------------------------------------------------------------------
def _bar(n_vertices):
    outer = np.array([[0, 0], [1, 0], [1, 0.2], [0, 0.2]], float)
    handles = [[0.96, 0.1], [0.02, 0.03], [0.02, 0.1], [0.02, 0.17]]
    return from_polygon(
        outer,
        (),
        handles,
        [True, False, False, False],
        [{"kind": "ellipse", "axes": [0.06, 0.3]}],
        n_vertices=n_vertices,
        name="bar",
        description="1 x 0.2 bar, left end clamped by 3 fixed handles, 1 moving handle at the right end (Fig. 3, 7); "
        "its region is a tall ellipse: pushing the end in by more than ~6% buckles the bar up or down (a jump)",
    )


def _u_shape(n_vertices):
    outer = np.array([[0, 0], [1, 0], [1, 1], [0.72, 1], [0.72, 0.3], [0.28, 0.3], [0.28, 1], [0, 1]], float)
    handles = [[0.14, 0.93], [0.86, 0.93], [0.1, 0.08], [0.5, 0.08], [0.9, 0.08], [0.5, 0.22]]
    moving = [True, True, False, False, False, False]
    regions = [{"kind": "disc", "radius": 0.2}, {"kind": "disc", "radius": 0.2}]
    return from_polygon(
        outer,
        (),
        handles,
        moving,
        regions,
        n_vertices=n_vertices,
        name="u_shape",
        description="U shape: the two arm tips move, the base is held by fixed handles (Fig. 4)",
    )


def _from_field(field, bbox, handles, moving, regions, n_vertices, name, description):
    outer, holes = implicit_outline(field, bbox)
    return from_polygon(
        outer, holes, handles, moving, regions, n_vertices=n_vertices, name=name, description=description
    )


def _gingerbread(n_vertices):
    f = union(
        ellipse((0, 0.78), 0.2, 0.2),  # head
        ellipse((0, 0.22), 0.26, 0.36),  # body
        capsule((-0.15, 0.42), (-0.55, 0.52), 0.11, 0.1),  # arms
        capsule((0.15, 0.42), (0.55, 0.52), 0.11, 0.1),
        capsule((-0.12, 0.0), (-0.3, -0.5), 0.13, 0.12),  # legs
        capsule((0.12, 0.0), (0.3, -0.5), 0.13, 0.12),
    )
    handles = [[-0.55, 0.52], [0.55, 0.52], [-0.3, -0.5], [0.3, -0.5], [0, 0.82]]
    r = [{"kind": "disc", "radius": 0.3}] * 5
    return _from_field(
        f,
        [[-0.8, -0.75], [0.8, 1.1]],
        handles,
        [True] * 5,
        r,
        n_vertices,
        "gingerbread",
        "gingerbread man with handles at the hands, feet and head (Fig. 6)",
    )


def _aleph(n_vertices):
    from matplotlib.font_manager import FontProperties  # font outline data, not plotting
    from matplotlib.textpath import TextPath

    tp = TextPath((0, 0), "\u05d0", prop=FontProperties(family="DejaVu Sans"), size=1)
    polys = [np.asarray(p) for p in tp.to_polygons()]
    outer = max(polys, key=lambda p: abs(polygon_area(p)))
    outer = (outer - outer.min(0)) / np.ptp(outer, axis=0).max()
    handles = _ALEPH_HANDLES
    r = 0.12
    regions = [{"kind": "disc", "radius": r}] * len(handles)
    return from_polygon(
        outer,
        (),
        handles,
        [True] * len(handles),
        regions,
        n_vertices=n_vertices,
        name="aleph",
        description="the Hebrew letter aleph from DejaVu Sans (TextPath), 5 handles (Fig. 8, 9)",
    )


# picked on the normalised DejaVu Sans glyph: the ends of the three strokes and the diagonal
_ALEPH_HANDLES = [[0.1, 0.95], [0.81, 0.93], [0.08, 0.05], [0.79, 0.05], [0.45, 0.5]]


def _octopus(n_vertices):
    parts = [ellipse((0, 0.35), 0.32, 0.38)]
    tips = []
    for k in range(8):
        ang = np.pi * (1.0 + k / 7)  # fan out below the head
        base = np.array([0.2 * np.cos(ang), 0.2 + 0.2 * np.sin(ang)])
        d = np.array([np.cos(ang), np.sin(ang)])
        nrm = np.array([-d[1], d[0]])
        s = np.linspace(0, 1, 12)
        curve = base + np.outer(s * 0.8, d) + np.outer(0.1 * np.sin(2 * np.pi * s) * s, nrm)
        parts.append(chain(curve, 0.075, 0.03))
        tips.append(curve[-1] - 0.03 * d)
    f = union(*parts)
    handles = np.vstack(tips + [np.array([[0, 0.5]])])
    mix = {
        "kind": "mixture",
        "components": [{"kind": "disc", "radius": 0.18}, {"kind": "voronoi", "radius": 0.45}],
        "weights": [0.5, 0.5],
    }
    regions = [mix] * 8 + [{"kind": "disc", "radius": 0.12}]
    return _from_field(
        f,
        [[-1.2, -1.0], [1.2, 0.85]],
        handles,
        [True] * 9,
        regions,
        n_vertices,
        "octopus",
        "octopus: 8 tentacle tips and the head; samples from discs and Voronoi cells (Fig. 1)",
    )


def _crab(n_vertices):
    parts = [ellipse((0, 0), 0.42, 0.28)]
    handles = []
    for sgn in (-1, 1):
        # claws: arm + two pincer fingers
        arm = np.array([[0.25 * sgn, 0.15], [0.45 * sgn, 0.4], [0.5 * sgn, 0.62]])
        parts.append(chain(arm, 0.07, 0.06))
        parts.append(ellipse((0.52 * sgn, 0.72), 0.11, 0.14))
        parts.append(capsule((0.46 * sgn, 0.78), (0.38 * sgn, 0.97), 0.05, 0.025))
        parts.append(capsule((0.6 * sgn, 0.78), (0.62 * sgn, 0.97), 0.05, 0.025))
        handles.append([0.52 * sgn, 0.72])
        # four legs per side
        for k in range(4):
            y0 = 0.08 - 0.12 * k
            knee = np.array([(0.62 - 0.03 * k) * sgn, y0 + 0.06])
            foot = np.array([(0.8 + 0.02 * k) * sgn, y0 - 0.3 - 0.08 * k])
            parts.append(chain(np.array([[0.15 * sgn, 0.6 * y0], knee, foot]), 0.042, 0.022))
            handles.append(foot - 0.03 * (foot - knee) / np.linalg.norm(foot - knee))
        parts.append(capsule((0.12 * sgn, 0.2), (0.14 * sgn, 0.36), 0.03, 0.035))  # eye stalks
    f = union(*parts)
    # 2 claws + 8 legs = 10 moving, 1 fixed at the body centre
    handles = np.vstack([handles, [[0.0, 0.0]]])
    moving = [True] * 10 + [False]
    regions = [{"kind": "disc", "radius": 0.15}] * 10
    return _from_field(
        f,
        [[-1.05, -1.0], [1.05, 1.05]],
        handles,
        moving,
        regions,
        n_vertices,
        "crab",
        "crab: claws and 8 legs move, the body centre is held (Fig. 2)",
    )


def _dino(n_vertices):
    body = ellipse((0, 0), 0.45, 0.25)
    neck = chain(np.array([[0.3, 0.1], [0.55, 0.45], [0.7, 0.75]]), 0.13, 0.08)
    head = ellipse((0.8, 0.8), 0.14, 0.08, angle=-0.2)
    tail = chain(np.array([[-0.35, 0.0], [-0.75, 0.1], [-1.05, 0.3], [-1.3, 0.35]]), 0.16, 0.03)
    legs = [capsule((x, -0.1), (x + 0.03, -0.55), 0.09, 0.07) for x in (-0.25, -0.1, 0.12, 0.27)]
    f = union(body, neck, head, tail, *legs)
    handles = [[0.85, 0.8], [-1.27, 0.35], [-0.22, -0.52], [0.3, -0.52]]
    moving = [True, True, False, False]
    regions = [{"kind": "disc", "radius": 0.3}] * 2
    return _from_field(
        f,
        [[-1.45, -0.7], [1.05, 1.0]],
        handles,
        moving,
        regions,
        n_vertices,
        "dino",
        "dinosaur: head and tail tip move, the feet stand (Table 1)",
    )


_BUILDERS = {
    "bar": (_bar, 600),
    "u_shape": (_u_shape, 800),
    "gingerbread": (_gingerbread, 1200),
    "aleph": (_aleph, 2900),
    "octopus": (_octopus, 4000),
    "crab": (_crab, 2100),
    "dino": (_dino, 1700),
}


def names():
    """Names of the built-in shapes.

    Returns
    -------
    names : list of str
    """
    return list(_BUILDERS)


def default_vertices(name):
    """The default vertex count of a named shape (near Table 1)."""
    _check_name(name)
    return _BUILDERS[name][1]


def _check_name(name):
    if name not in _BUILDERS:
        raise ValueError(f"unknown shape {name!r}; known shapes: {', '.join(_BUILDERS)}")


@functools.lru_cache(maxsize=32)
def _load(name, n_vertices):
    builder, default = _BUILDERS[name]
    return builder(n_vertices or default)


def load(name, n_vertices=None):
    """One of the paper's models as a :class:`Shape`.

    Parameters
    ----------
    name : str
        One of :func:`names`.
    n_vertices : int, optional
        About how many mesh vertices (default: near Table 1).

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
    if n_vertices is not None and (int(n_vertices) != n_vertices or n_vertices < 20):
        raise ValueError(f"n_vertices must be an integer >= 20, got {n_vertices!r}")
    s = _load(name, None if n_vertices is None else int(n_vertices))
    mesh = Mesh(s.mesh.V.copy(), s.mesh.F.copy())
    return Shape(
        s.name,
        mesh,
        s.handles.copy(),
        s.moving.copy(),
        [dict(r) for r in s.regions],
        s.description,
        [L.copy() for L in s.outline],
    )
