"""Matplotlib drawing helpers (presentation only; the core never imports this module).

Colours follow the paper: moving handles red, fixed handles blue (Fig. 4), sampling regions
drawn as translucent outlines around the moving handles.
"""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from .regions import as_region

MOVING = "#d62728"
FIXED = "#1f77b4"
FILL = "#f2d7a6"
REGION = "#ff7f0e"


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
        art = ax.tripcolor(P[:, 0], P[:, 1], F, facecolors=np.zeros(len(F)), cmap=_single(color), **kw)
    else:
        scalars = np.asarray(scalars)
        key = "facecolors" if len(scalars) == len(F) and len(F) != len(P) else "C"
        art = ax.tripcolor(P[:, 0], P[:, 1], F, **{key: scalars}, **kw)
    if edges:
        ax.triplot(P[:, 0], P[:, 1], F, color=edge_color, lw=lw)
    ax.set_aspect("equal")
    ax.set_axis_off()
    return art


def _single(color):
    from matplotlib.colors import ListedColormap

    return ListedColormap([color])


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
    """Closed outlines of a sampling region, for drawing (see :meth:`defop.regions.Region.outlines`).

    Parameters
    ----------
    center : (2,) numpy array
        The moving handle's rest position p_l.
    region : defop.regions.Region or dict
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
    regions : list of defop.regions.Region or dict
        One region per moving handle.
    """
    for i, (c, region) in enumerate(zip(np.asarray(P_moving), regions, strict=True)):
        for poly, ls in region_outlines(c, region, P_moving, i):
            if len(poly) < 3:
                continue
            ax.add_patch(patches.Polygon(poly, closed=True, fill=(ls == "-"), alpha=0.15, color=color))
            ax.add_patch(patches.Polygon(poly, closed=True, fill=False, ls=ls, lw=1.0, color=color))


def plot_shape(ax, shape, X=None, regions=True, title=True, edges=True):
    """Draw a :class:`defop.shapes.Shape`: its mesh, handles and sampling regions.

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.shapes.Shape
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
    shapes : list of defop.shapes.Shape
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


def plot_deformation(ax, shape, X, highlight_flips=True, title=None, edges=True, flip_color="#e31a1c", zoom_flips=True):
    """Draw a deformed shape, its handles, and its flipped triangles in red.

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.shapes.Shape
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
            ax.tripcolor(
                X[:, 0],
                X[:, 1],
                mesh.F[flipped],
                facecolors=np.zeros(flipped.sum()),
                cmap=_single(flip_color),
                zorder=3,
            )
            if zoom_flips:
                c = X[mesh.F[np.flatnonzero(flipped)[0]]].mean(axis=0)
                r = 0.04 * mesh.bbox_diagonal
                ins = ax.inset_axes([0.62, 0.02, 0.36, 0.36])
                plot_mesh(ins, mesh.V, mesh.F, X, edges=True, lw=0.5)
                ins.tripcolor(
                    X[:, 0],
                    X[:, 1],
                    mesh.F[flipped],
                    facecolors=np.zeros(flipped.sum()),
                    cmap=_single(flip_color),
                    zorder=3,
                )
                plot_handles(ins, X, shape.handles, shape.moving, size=15)
                ins.set_xlim(c[0] - r, c[0] + r)
                ins.set_ylim(c[1] - r, c[1] + r)
                ins.set_axis_on()
                ins.set_xticks([])
                ins.set_yticks([])
                ax.indicate_inset_zoom(ins, edgecolor="k")
    plot_handles(ax, X, shape.handles, shape.moving)
    if title:
        ax.set_title(title, fontsize=9)
    ax.autoscale_view()


def plot_handle_zoom(ax, shape, X, vertex, radius=0.12, vmax=90.0, flip_color="#e31a1c"):
    """The neighbourhood of one handle, triangles coloured by their largest corner-angle change (Fig. 6's cusps).

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.shapes.Shape
    X : (n,2) numpy array
        Deformed positions.
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
    from .analysis import corner_angles

    mesh = shape.mesh
    change = np.degrees(np.abs(corner_angles(X, mesh.F) - corner_angles(mesh.V, mesh.F))).max(axis=1)
    art = plot_mesh(ax, mesh.V, mesh.F, X, scalars=change, cmap="magma_r", vmin=0, vmax=vmax, lw=0.5)
    flipped = mesh.flipped(X)
    if flipped.any():
        ax.tripcolor(
            X[:, 0], X[:, 1], mesh.F[flipped], facecolors=np.zeros(flipped.sum()), cmap=_single(flip_color), zorder=3
        )
    plot_outline(ax, mesh, X, lw=0.8)
    plot_handles(ax, X, shape.handles, shape.moving, size=25)
    c = X[vertex]
    ax.set_xlim(c[0] - radius, c[0] + radius)
    ax.set_ylim(c[1] - radius, c[1] + radius)
    return art


def plot_energy_comparison(axes, zooms, shape, results, titles, vertex, radius=0.12):
    """Fig. 6: one column per energy, the deformation over the rest outline (dashed) and a zoom on one handle.

    Parameters
    ----------
    axes, zooms : sequences of matplotlib Axes
        One each per entry of ``results``.
    shape : defop.shapes.Shape
    results : dict of str -> defop.solve.SolveResult
    titles : dict of str -> str
        Panel title per energy.
    vertex : int
        The handle vertex the zooms centre on.

    Returns
    -------
    artist : the last zoom's colour-mapped PolyCollection (for a colour bar)
    """
    from .analysis import deformation_summary

    art = None
    for ax, zoom, (energy, r) in zip(axes, zooms, results.items()):
        s = deformation_summary(shape.mesh, r.X, shape.moving_handles)
        plot_outline(ax, shape.mesh, shape.mesh.V, color="0.45", lw=0.7, ls="--")
        area, scaled = 100 * s["area_change"], 100 * s["scaled"]
        title = f"{titles[energy]}\n{s['flips']} flipped, area {area:+.0f}%, {scaled:.0f}% scaled"
        plot_deformation(ax, shape, r.X, title=title, zoom_flips=False)
        art = plot_handle_zoom(zoom, shape, r.X, vertex, radius)
        zoom.set_title(f"max over the handles: {s['handle_angle']:.0f}°", fontsize=8)
    return art


def plot_convergence(axes, results, E_star=None, labels=None):
    """Energy gap (E − E*)/E* against iteration and against time, one line per solver.

    Parameters
    ----------
    axes : (2,) sequence of matplotlib Axes
        Iteration axis, time axis.
    results : dict of str -> defop.solve.SolveResult
    E_star : float, optional
        Reference minimum (default: the lowest energy any result reached).
    """
    if E_star is None:
        E_star = min(float(np.min(r.energy_history)) for r in results.values())
    for name, r in results.items():
        gap = np.maximum((r.energy_history - E_star) / E_star, 1e-16)
        axes[0].semilogy(np.arange(len(gap)), gap, label=name)
        axes[1].loglog(np.maximum(r.time_history, 1e-4), gap, label=name)
    axes[0].set_xlabel("iteration")
    axes[1].set_xlabel("time [s]")
    for ax in axes:
        ax.set_ylabel("(E − E*) / E*")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)


def plot_outline(ax, mesh, X, color="k", lw=1.0, ls="-", **kw):
    """Draw the boundary loops of a deformed mesh (e.g. the ground truth over an approximation).

    Parameters
    ----------
    ax : matplotlib Axes
    mesh : defop.mesh.Mesh
    X : (n,2) numpy array
    """
    for loop in mesh.boundary_loops():
        P = X[np.append(loop, loop[0])]
        ax.plot(P[:, 0], P[:, 1], color=color, lw=lw, ls=ls, **kw)


def plot_bases_grid(shape, Q, X_true, operators, titles=None, size=2.2):
    """Rows = operators, columns = handle configurations; each panel: D(·, Q) filled, ground truth outlined.

    Parameters
    ----------
    shape : defop.shapes.Shape
    Q : (k,n,2) numpy array
    X_true : (k,n_vertices,2) numpy array
    operators : dict of str -> DefOp
    titles : list of str, optional
        Column titles.

    Returns
    -------
    fig : matplotlib Figure
    """
    k = len(Q)
    rows = len(operators)
    fig, axes = plt.subplots(rows, k, figsize=(size * k, 0.9 * size * rows), squeeze=False)
    allX = np.concatenate([X_true.reshape(-1, 2)] + [op(Q).reshape(-1, 2) for op in operators.values()])
    lo, hi = allX.min(axis=0), allX.max(axis=0)
    pad = 0.05 * (hi - lo).max()
    for r, (name, op) in enumerate(operators.items()):
        D = op(Q)
        for c in range(k):
            ax = axes[r, c]
            plot_mesh(ax, shape.mesh.V, shape.mesh.F, D[c], edges=False)
            plot_outline(ax, shape.mesh, X_true[c], lw=0.8)
            plot_handles(ax, D[c], shape.handles, shape.moving, size=12)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            if c == 0:
                ax.text(-0.02, 0.5, name, transform=ax.transAxes, rotation=90, ha="right", va="center", fontsize=10)
            if r == 0 and titles is not None:
                ax.set_title(titles[c], fontsize=8)
    fig.tight_layout()
    return fig
