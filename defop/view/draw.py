"""Matplotlib drawing primitives: meshes, handles, sampling regions, outlines and keys (presentation only).

Colours follow the paper: moving handles red, fixed handles blue (Fig. 4), sampling regions drawn as translucent
outlines around the moving handles. The lessons' figures (:mod:`.plot`) are composed of these.
"""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from ..scene.regions import as_region

__all__ = [
    "NAMES",
    "MOVING",
    "FIXED",
    "FILL",
    "REGION",
    "FLIP",
    "plot_mesh",
    "single_colormap",
    "fill_triangles",
    "plot_handles",
    "region_outlines",
    "plot_regions",
    "plot_shape",
    "shape_gallery",
    "plot_deformation",
    "plot_handle_zoom",
    "plot_outline",
    "key_legend",
    "figure_key",
    "cell_edges",
    "readable",
]

#: readable names of the energies and handle bases, for titles (never a code identifier such as "sarap")
NAMES = {
    "arap": "ARAP",
    "sarap": "S-ARAP",
    "isometric": "symmetric Dirichlet",
    "linear": "linear",
    "quadratic": "quadratic",
    "cubic": "cubic",
    "tps": "TPS",
    "hat": "hat functions",
    "reduced": "reduced",
}

MOVING = "#d62728"
FIXED = "#1f77b4"
FILL = "#f2d7a6"
REGION = "#ff7f0e"
FLIP = "#e31a1c"


def plot_mesh(ax, V, F, X=None, color=FILL, edges=True, edge_color="#00000040", lw=0.3, scalars=None, **kw):
    """Draw a (deformed) triangle mesh.

    Parameters
    ----------
    ax : matplotlib Axes
    V : (n,2) numpy array
        Rest positions (drawn when ``X`` is None).
    F : (m,3) numpy array
        Triangles.
    X : (n,2) numpy array, optional
        Deformed positions.
    color : str
        Fill colour when ``scalars`` is None.
    edges : bool
        Draw the triangle edges.
    scalars : (m,) or (n,) numpy array, optional
        Colour per triangle or per vertex (``tripcolor``).

    Returns
    -------
    artist : the fill artist (a PolyCollection)
    """
    P = np.asarray(V if X is None else X)
    F = np.asarray(F)
    if scalars is None:
        art = ax.tripcolor(P[:, 0], P[:, 1], F, facecolors=np.zeros(len(F)), cmap=single_colormap(color), **kw)
    else:
        scalars = np.asarray(scalars)
        key = "facecolors" if len(scalars) == len(F) and len(F) != len(P) else "C"
        art = ax.tripcolor(P[:, 0], P[:, 1], F, **{key: scalars}, **kw)
    if edges:
        ax.triplot(P[:, 0], P[:, 1], F, color=edge_color, lw=lw)
    ax.set_aspect("equal")
    ax.set_axis_off()
    return art


def single_colormap(color):
    """A colour map of one colour: ``tripcolor`` with it fills every triangle in ``color``."""
    from matplotlib.colors import ListedColormap

    return ListedColormap([color])


def fill_triangles(ax, X, F, color=FLIP):
    """Fill the triangles ``F`` of the deformed positions ``X`` (n,2) in one colour, above the mesh (flipped ones).

    Returns
    -------
    artist : the PolyCollection
    """
    return ax.tripcolor(
        X[:, 0],
        X[:, 1],
        F,
        facecolors=np.zeros(len(F)),
        cmap=single_colormap(color),
        zorder=3,
    )


def plot_handles(ax, X, handles, moving=None, size=30, zorder=5):
    """Draw handles: moving ones red, fixed ones blue.

    Parameters
    ----------
    ax : matplotlib Axes
    X : (n,2) numpy array
        Vertex positions (rest or deformed).
    handles : (h,) int numpy array
        Handle vertex indices.
    moving : (h,) bool numpy array, optional
        All moving when None.
    """
    handles = np.asarray(handles, dtype=int)
    moving = np.ones(len(handles), bool) if moving is None else np.asarray(moving, bool)
    X = np.asarray(X)
    ax.scatter(*X[handles[~moving]].T, s=size, c=FIXED, zorder=zorder, edgecolors="k", linewidths=0.5)
    ax.scatter(*X[handles[moving]].T, s=size, c=MOVING, zorder=zorder + 1, edgecolors="k", linewidths=0.5)


def region_outlines(center, region, P=None, index=None, n=96):
    """Closed outlines of a sampling region, for drawing (see :meth:`defop.scene.regions.Region.outlines`).

    Parameters
    ----------
    center : (2,) numpy array
        The moving handle's rest position p_l.
    region : defop.scene.regions.Region or dict
    P : (n,2) numpy array, optional
        All moving handles' rest positions (needed for ``voronoi``).
    index : int, optional
        Row of ``center`` in ``P`` (needed for ``voronoi``).
    n : int
        Points per circle.

    Returns
    -------
    outlines : list of ((k,2) numpy array, str)
        Polygons with a line style (``"-"``, ``"--"`` or ``":"``).
    """
    return as_region(region).outlines(center, P, index, n)


def plot_regions(ax, P_moving, regions, color=REGION):
    """Draw the sampling region of every moving handle.

    Parameters
    ----------
    ax : matplotlib Axes
    P_moving : (n,2) numpy array
        Rest positions of the moving handles.
    regions : list of defop.scene.regions.Region or dict
        One region per moving handle.
    """
    for i, (c, region) in enumerate(zip(np.asarray(P_moving), regions, strict=True)):
        for poly, ls in region_outlines(c, region, P_moving, i):
            if len(poly) < 3:
                continue
            ax.add_patch(patches.Polygon(poly, closed=True, fill=(ls == "-"), alpha=0.15, color=color))
            ax.add_patch(patches.Polygon(poly, closed=True, fill=False, ls=ls, lw=1.0, color=color))


def plot_shape(ax, shape, X=None, regions=True, title=True, edges=True):
    """Draw a :class:`defop.scene.shapes.Shape`: its mesh, handles and sampling regions.

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.scene.shapes.Shape
    X : (n,2) numpy array, optional
        Deformed positions (rest pose when None).
    regions : bool
        Draw the sampling regions (at rest positions).
    title : bool or str
        Title text; ``True`` uses the name and vertex count.
    """
    mesh = shape.mesh
    plot_mesh(ax, mesh.V, mesh.F, X, edges=edges)
    if regions and X is None:
        plot_regions(ax, shape.P_moving, shape.regions)
    plot_handles(ax, mesh.V if X is None else X, shape.handles, shape.moving)
    if title is True:
        n_fixed = len(shape.handles) - shape.n_moving
        title = f"{shape.name}  ({mesh.n_vertices} v, {shape.n_moving} moving, {n_fixed} fixed)"
    if title:
        ax.set_title(title, fontsize=9)
    ax.autoscale_view()


def shape_gallery(shapes, ncols=4, size=3.2):
    """A grid of every shape with its handles and sampling regions.

    Parameters
    ----------
    shapes : list of defop.scene.shapes.Shape
    ncols : int
    size : float
        Inches per panel.

    Returns
    -------
    fig : matplotlib Figure
    """
    nrows = -(-len(shapes) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(size * ncols, size * nrows), squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for ax, shape in zip(axes.flat, shapes, strict=False):
        plot_shape(ax, shape)
    fig.tight_layout()
    return fig


def plot_deformation(ax, shape, X, highlight_flips=True, title=None, edges=True, flip_color=FLIP, zoom_flips=True):
    """Draw a deformed shape, its handles, and its flipped triangles in red.

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.scene.shapes.Shape
    X : (n,2) numpy array
        Deformed positions.
    highlight_flips : bool
        Fill triangles with det J <= 0 in ``flip_color``.
    title : str, optional
    zoom_flips : bool
        Add an inset magnifying the first flipped region.
    """
    mesh = shape.mesh
    plot_mesh(ax, mesh.V, mesh.F, X, edges=edges)
    if highlight_flips:
        flipped = mesh.flipped(X)
        if flipped.any():
            fill_triangles(ax, X, mesh.F[flipped], flip_color)
            if zoom_flips:
                _zoom_on_flips(ax, shape, X, flipped, flip_color)
    plot_handles(ax, X, shape.handles, shape.moving)
    if title:
        ax.set_title(title, fontsize=9)
    ax.autoscale_view()


def _zoom_on_flips(ax, shape, X, flipped, flip_color):
    """An inset of ``ax`` magnifying the first flipped triangle of the deformed shape, flips filled."""
    mesh = shape.mesh
    c = X[mesh.F[np.flatnonzero(flipped)[0]]].mean(axis=0)
    r = 0.04 * mesh.bbox_diagonal
    ins = ax.inset_axes([0.62, 0.02, 0.36, 0.36])
    plot_mesh(ins, mesh.V, mesh.F, X, edges=True, lw=0.5)
    fill_triangles(ins, X, mesh.F[flipped], flip_color)
    plot_handles(ins, X, shape.handles, shape.moving, size=15)
    ins.set_xlim(c[0] - r, c[0] + r)
    ins.set_ylim(c[1] - r, c[1] + r)
    ins.set_axis_on()
    ins.set_xticks([])
    ins.set_yticks([])
    ax.indicate_inset_zoom(ins, edgecolor="k")


def plot_handle_zoom(ax, shape, X, vertex, radius=0.12, vmax=90.0, flip_color=FLIP):
    """The neighbourhood of one handle, triangles coloured by their largest corner-angle change (Fig. 6's cusps).

    Parameters
    ----------
    ax, shape, X
        As in :func:`plot_deformation`.
    vertex : int
        The handle vertex to centre on.
    radius : float
        Half-width of the window, in the shape's units.
    vmax : float
        Angle change (degrees) at the top of the colour map; flipped triangles are drawn in ``flip_color``.

    Returns
    -------
    artist : the PolyCollection coloured by angle change (for a colour bar)
    """
    from ..analysis.distortion import corner_angles

    mesh = shape.mesh
    change = np.degrees(np.abs(corner_angles(X, mesh.F) - corner_angles(mesh.V, mesh.F))).max(axis=1)
    art = plot_mesh(ax, mesh.V, mesh.F, X, scalars=change, cmap="magma_r", vmin=0, vmax=vmax, lw=0.5)
    flipped = mesh.flipped(X)
    if flipped.any():
        fill_triangles(ax, X, mesh.F[flipped], flip_color)
    plot_outline(ax, mesh, X, lw=0.8)
    plot_handles(ax, X, shape.handles, shape.moving, size=25)
    c = X[vertex]
    ax.set_xlim(c[0] - radius, c[0] + radius)
    ax.set_ylim(c[1] - radius, c[1] + radius)
    return art


def plot_outline(ax, mesh, X, color="k", lw=1.0, ls="-", **kw):
    """Draw the boundary loops of a deformed mesh (e.g. the ground truth over an approximation).

    Parameters
    ----------
    ax : matplotlib Axes
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array
    """
    for loop in mesh.boundary_loops():
        P = X[np.append(loop, loop[0])]
        ax.plot(P[:, 0], P[:, 1], color=color, lw=lw, ls=ls, **kw)


def key_legend(fig, items, **kw):
    """A frameless figure legend of ``items``, (artist, text) pairs: the keys of the lessons' figures."""
    kw.setdefault("fontsize", 8)
    return fig.legend([h for h, _ in items], [t for _, t in items], frameon=False, **kw)


def figure_key(fig, fill="operator D(·, Q)", outline="ground truth", fixed=False, extra=(), y=0.0, ncol=None):
    """A key below a figure for the marks of the deformation panels: fill, outline, handles and ``extra``.

    Parameters
    ----------
    fig : matplotlib Figure
    fill, outline : str or None
        Labels of the filled shape and of its black outline (None leaves one out).
    fixed : bool
        Also key the fixed handles (blue).
    extra : sequence of (matplotlib artist, str)
        Further entries.
    y : float
        Figure coordinate of the key's top edge.

    Returns
    -------
    legend : matplotlib Legend
    """
    from matplotlib.lines import Line2D

    dot = dict(marker="o", ls="none", mec="k", mew=0.5, ms=6)
    items = []
    if fill:
        items.append((patches.Patch(facecolor=FILL, edgecolor="none"), fill))
    if outline:
        items.append((Line2D([], [], color="k", lw=1.0), outline))
    items.append((Line2D([], [], mfc=MOVING, **dot), "moving handle"))
    if fixed:
        items.append((Line2D([], [], mfc=FIXED, **dot), "fixed handle"))
    items += list(extra)
    return key_legend(fig, items, loc="upper center", bbox_to_anchor=(0.5, y), ncol=ncol or len(items), fontsize=8)


def cell_edges(centres):
    """(k+1,) edges of the cells around k increasing grid values (for ``pcolormesh``: each value fills its cell)."""
    c = np.asarray(centres, float)
    step = np.gradient(c) / 2 if len(c) > 1 else np.array([0.5])
    return np.concatenate([c - step, [c[-1] + step[-1]]])


def readable(name):
    """The readable name of an energy or a handle basis (``"sarap"`` -> ``"S-ARAP"``); other names unchanged."""
    return NAMES.get(name, name)
