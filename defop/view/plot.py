"""Matplotlib drawing helpers (presentation only; the core never imports this module).

Colours follow the paper: moving handles red, fixed handles blue (Fig. 4), sampling regions
drawn as translucent outlines around the moving handles.
"""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from ..scene.regions import as_region

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


def plot_handle_zoom(ax, shape, X, vertex, radius=0.12, vmax=90.0, flip_color=FLIP):
    """The neighbourhood of one handle, triangles coloured by their largest corner-angle change (Fig. 6's cusps).

    Parameters
    ----------
    ax : matplotlib Axes
    shape : defop.scene.shapes.Shape
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
    from ..analysis.distortion import corner_angles

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


def plot_energy_comparison(axes, zooms, shape, results, titles, vertex, radius=0.12, vmax=None):
    """Fig. 6: one column per energy, the deformation over the rest outline (dashed) and a zoom on one handle.

    Parameters
    ----------
    axes, zooms : sequences of matplotlib Axes
        One each per entry of ``results``.
    shape : defop.scene.shapes.Shape
    results : dict of str -> defop.variational.solver.SolveResult
    titles : dict of str -> str
        Panel title per energy.
    vertex : int
        The handle vertex the zooms centre on.
    vmax : float, optional
        Angle change (degrees) at the top of the colour map; default: the largest change at any handle over all
        results, rounded up to 30°, so the colour bar covers every value drawn.

    Returns
    -------
    artist : the last zoom's colour-mapped PolyCollection (for a colour bar)
    """
    from ..analysis.distortion import deformation_summary

    summary = {energy: deformation_summary(shape.mesh, r.X, shape.moving_handles) for energy, r in results.items()}
    if vmax is None:
        vmax = 30.0 * np.ceil(max(max(s["handle_angle"] for s in summary.values()), 90.0) / 30.0)
    art = None
    for ax, zoom, (energy, r) in zip(axes, zooms, results.items()):
        s = summary[energy]
        plot_outline(ax, shape.mesh, shape.mesh.V, color="0.45", lw=0.7, ls="--")
        area, scaled = 100 * s["area_change"], 100 * s["scaled"]
        title = f"{titles[energy]}\n{s['flips']} flipped, area {area:+.0f}%, {scaled:.0f}% scaled"
        plot_deformation(ax, shape, r.X, title=title, zoom_flips=False)
        art = plot_handle_zoom(zoom, shape, r.X, vertex, radius, vmax=vmax)
        zoom.set_title(f"largest change at a handle: {s['handle_angle']:.0f}°", fontsize=8)
    return art


def plot_energies_figure(shape, results, titles, vertex, solvers, E_star=None):
    """Fig. 6 whole: the energies' deformations, zooms coloured by corner-angle change, and the solver race.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    results : dict of str -> SolveResult
        One deformation per energy (``X``).
    titles : dict of str -> str
    vertex : int
        The handle the zooms centre on.
    solvers : dict of str -> SolveResult
        With ``energy_history`` and ``time_history`` (:func:`plot_convergence`).
    E_star : float, optional

    Returns
    -------
    fig : matplotlib Figure
    """
    from matplotlib.lines import Line2D

    k = len(results)
    fig = plt.figure(figsize=(max(3.2 * k, 14.0), 10.5))
    grid = fig.add_gridspec(3, 2 * k + 1, height_ratios=[1.25, 0.75, 0.8], hspace=0.45)
    tops = [fig.add_subplot(grid[0, 2 * i : 2 * i + 2]) for i in range(k)]
    zooms = [fig.add_subplot(grid[1, 2 * i : 2 * i + 2]) for i in range(k)]
    art = plot_energy_comparison(tops, zooms, shape, results, titles, vertex)
    holder = fig.add_subplot(grid[1, 2 * k])
    holder.set_axis_off()
    cax = holder.inset_axes([0.1, 0.0, 0.25, 1.0])
    fig.colorbar(art, cax=cax, label="largest corner-angle change [°]")
    race = grid[2, :].subgridspec(1, 2, wspace=0.25)
    axes = [fig.add_subplot(race[0]), fig.add_subplot(race[1])]
    plot_convergence(axes, solvers, E_star)
    axes[0].set_title("S-ARAP, half the move: projected Newton (ours) against L-BFGS (the paper's)", fontsize=9)
    axes[1].set_title("the same, against time", fontsize=9)
    key = [
        (patches.Patch(facecolor=FILL), "deformed shape"),
        (Line2D([], [], color="0.45", lw=0.7, ls="--"), "rest outline"),
        (Line2D([], [], marker="o", mfc=MOVING, mec="k", ls="none"), "moving handle"),
        (patches.Patch(color=FLIP), "flipped triangle"),
    ]
    key_legend(fig, key, loc="upper center", bbox_to_anchor=(0.5, 0.955), ncol=4, fontsize=9)
    fig.suptitle("Fig. 6: variational deformations with different energies; second row: the right hand's handle")
    return fig


def plot_convergence(axes, results, E_star=None, labels=None):
    """Energy gap (E − E*)/E* against iteration and against time, one line per solver.

    Parameters
    ----------
    axes : (2,) sequence of matplotlib Axes
        Iteration axis, time axis.
    results : dict of str -> defop.variational.solver.SolveResult
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


def plot_bases_grid(shape, Q, X_true, operators, titles=None, size=2.2, notes=None):
    """Rows = operators, columns = handle configurations; each panel: D(·, Q) filled, ground truth outlined.

    A key below the panels names the fill, the outline and the handles.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    Q : (k,n,2) numpy array
    X_true : (k,n_vertices,2) numpy array
    operators : dict of str -> DefOp or None
        Row label -> operator; a None row shows an empty panel saying "not fitted" (e.g. a basis that needs more
        samples), with the row's note under it.
    titles : list of str, optional
        Column titles.
    notes : dict of str -> list of str, optional
        Row label -> one short text per column, printed under the panel (e.g. its error), clear of the shapes.

    Returns
    -------
    fig : matplotlib Figure
    """
    k = len(Q)
    rows = len(operators)
    fig, axes = plt.subplots(rows, k, figsize=(size * k, size * rows), squeeze=False)
    D = {name: None if op is None else op(Q) for name, op in operators.items()}
    allX = np.concatenate([X_true.reshape(-1, 2)] + [d.reshape(-1, 2) for d in D.values() if d is not None])
    lo, hi = allX.min(axis=0), allX.max(axis=0)
    pad = 0.05 * (hi - lo).max()
    for r, name in enumerate(operators):
        for c in range(k):
            ax = axes[r, c]
            note = notes[name][c] if notes is not None and name in notes else ""
            if D[name] is None:
                ax.text(
                    0.5,
                    0.5,
                    "not fitted\n" + note,
                    transform=ax.transAxes,
                    ha="center",
                    va="center",
                    fontsize=8,
                    color="0.4",
                )
                note = ""
            else:
                plot_mesh(ax, shape.mesh.V, shape.mesh.F, D[name][c], edges=False)
                plot_handles(ax, D[name][c], shape.handles, shape.moving, size=12)
                plot_outline(ax, shape.mesh, X_true[c], lw=0.8)
            ax.set_aspect("equal")
            ax.set_axis_off()
            if note:
                ax.text(0.5, -0.01, note, transform=ax.transAxes, ha="center", va="top", fontsize=7)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            if c == 0:
                label = readable(name)  # a basis name as a word: "tps" -> "TPS"
                ax.text(-0.02, 0.5, label, transform=ax.transAxes, rotation=90, ha="right", va="center", fontsize=10)
            if r == 0 and titles is not None:
                ax.set_title(titles[c], fontsize=8)
    fig.tight_layout(h_pad=1.2)
    figure_key(fig, fixed=not np.all(shape.moving))
    return fig


def cell_edges(centres):
    """(k+1,) edges of the cells around k increasing grid values (for ``pcolormesh``: each value fills its cell)."""
    c = np.asarray(centres, float)
    step = np.gradient(c) / 2 if len(c) > 1 else np.array([0.5])
    return np.concatenate([c - step, [c[-1] + step[-1]]])


def readable(name):
    """The readable name of an energy or a handle basis (``"sarap"`` -> ``"S-ARAP"``); other names unchanged."""
    return NAMES.get(name, name)


def plot_gallery(panels, rms, size=3.4):
    """Fig. 11: per model, the ground truth (top) and the DefOp at the same Q (bottom, ground truth outlined).

    Parameters
    ----------
    panels : sequence of (Shape, DefOp, (n,2) numpy array, (n_vertices,2) numpy array)
        Model, operator, held-out configuration Q and its ground truth.
    rms : dict of str -> float
        RMS vertex error over the bounding-box diagonal, per model name.

    Returns
    -------
    fig : matplotlib Figure
    """
    fig, axes = plt.subplots(2, len(panels), figsize=(size * len(panels), 6.8), squeeze=False)
    for k, (shape, op, q, X) in enumerate(panels):
        energy, basis = readable(op.energy), readable(op.handle_basis.kind)
        plot_deformation(axes[0, k], shape, X, edges=False, title=f"{shape.name}\n{energy} ground truth")
        plot_deformation(
            axes[1, k],
            shape,
            op(q),
            edges=False,
            title=f"DefOp, {basis} Ψ, m = {op.n_samples}\nRMS error {100 * rms[shape.name]:.2g}% of the diagonal",
        )
        plot_outline(axes[1, k], shape.mesh, X, lw=0.6)
    fig.suptitle("Fig. 11: ground truths (top) and their real-time approximations (bottom, ground truth outlined)")
    fig.tight_layout()
    fixed = any(not np.all(shape.moving) for shape, *_ in panels)
    flips = any(shape.mesh.flipped(op(q)).any() or shape.mesh.flipped(X).any() for shape, op, q, X in panels)
    extra = [(patches.Patch(color=FLIP), "flipped triangle (inset: magnified)")] if flips else []
    figure_key(
        fig, fill="DefOp (bottom) / ground truth (top)", outline="ground truth (bottom)", fixed=fixed, extra=extra
    )
    return fig


def plot_local_vs_global(shape, grid, runs, jumps, vertex, col, rows, show, first_up=True):
    """Fig. 10: deformations and the star's trajectory from global and from local (dragged) optima.

    Left: one row per entry of ``show``, the bar at the handle positions ``rows`` of column ``col``. Then a
    heat map of the star's y-displacement T_y over the handle plane (cells with their true edges, ○ the
    positions shown at left, × the jump in each column, ▲/▼ the direction each column was dragged in), one
    colour bar for both, and on the right the trajectory and the energy along column ``col``.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    grid : defop.analysis.trajectories.HandleGrid
    runs : dict of str -> defop.analysis.trajectories.Trajectory
        With an ``energy`` (ny, nx) array each; the entries other than ``"rest"`` are drawn on the right.
    jumps : dict of str -> (nx,) numpy array
        Per column, the q_y − p_y of the jump (NaN: none).
    vertex : int
        The starred point.
    col : int
        The column of the deformation panels and of the right-hand plots.
    rows : sequence of int
        Grid rows of the deformation panels.
    show : dict of str -> str
        Run name -> row label; a name starting with "local" gets the drag arrows.
    first_up : bool
        The drag went up column 0 (then down column 1, ...).

    Returns
    -------
    fig : matplotlib Figure
    """
    from matplotlib.lines import Line2D

    nrow, ncol = len(show), len(rows)
    fig, axes = plt.subplots(
        nrow,
        ncol + 2,
        figsize=(4.0 * ncol + 9, 3.6 * nrow),
        layout="constrained",
        squeeze=False,
        gridspec_kw={"width_ratios": [1] * ncol + [1.1, 1.25]},
    )
    xe, ye = cell_edges(grid.xs), cell_edges(grid.ys)
    vmax = max(np.abs(r.of(vertex)[..., 1]).max() for r in runs.values())
    for a, (k, label) in zip(axes, show.items()):
        r = runs[k]
        for ax, i in zip(a, rows):
            where = f"q − p = ({grid.xs[col]:+.2f}, {grid.ys[i]:+.3f})"
            plot_deformation(ax, shape, r.X[i, col], edges=False, title=f"{label}\n{where}")
            ax.plot(*r.X[i, col, vertex], "k*", ms=9)
            ax.set_xlim(-0.1, 1.05), ax.set_ylim(-0.45, 0.65)
        hm = a[ncol]
        im = hm.pcolormesh(xe, ye, r.of(vertex)[..., 1], cmap="coolwarm", vmin=-vmax, vmax=vmax, shading="flat")
        hm.plot(np.full(len(rows), grid.xs[col]), grid.ys[rows], "ko", mfc="none", ms=7, clip_on=False, zorder=4)
        hm.plot(grid.xs, jumps[k], "kx", ms=6, zorder=4)
        if k.startswith("local"):
            up = (np.arange(len(grid.xs)) % 2 == 0) == first_up
            for j, u in enumerate(up):
                hm.plot(grid.xs[j], ye[-1], "^" if u else "v", color="k", ms=4, clip_on=False, zorder=4)
        hm.set_xlim(xe[0], xe[-1]), hm.set_ylim(ye[0], ye[-1])
        hm.set_title(f"{label}: T_y of the star", fontsize=9, pad=10)
        hm.set_xlabel("q_x − p_x"), hm.set_ylabel("q_y − p_y")
    fig.colorbar(im, ax=axes[:, ncol], shrink=0.85, location="right", label="T_y: y-displacement of the star")
    styles = {k: "o-" if k == "global" else ".--" for k in runs if k != "rest"}
    right = axes[:, ncol + 1]
    for k, st in styles.items():
        right[0].plot(grid.ys, runs[k].of(vertex)[:, col, 1], st, label=k)
        if nrow > 1:
            right[1].plot(grid.ys, runs[k].energy[:, col], st, label=k)
    right[0].set_title(f"along the column q_x − p_x = {grid.xs[col]:+.2f}", fontsize=9)
    right[0].set_ylabel("T_y of the star")
    if nrow > 1:
        right[1].set_ylabel("S-ARAP energy")
    for ax in right:
        ax.set_xlabel("q_y − p_y"), ax.legend(fontsize=7), ax.grid(alpha=0.3)
    mark = dict(ls="none", color="k")
    key = [
        (patches.Patch(facecolor=FILL), "the bar"),
        (Line2D([], [], marker="*", ms=9, **mark), "the star (a mid-bar point)"),
        (Line2D([], [], marker="o", mfc=MOVING, mec="k", ls="none"), "moving handle"),
        (Line2D([], [], marker="o", mfc=FIXED, mec="k", ls="none"), "fixed handles"),
        (Line2D([], [], marker="o", mfc="none", ms=7, **mark), "handle positions shown at left"),
        (Line2D([], [], marker="x", ms=6, **mark), "jump of T_y in a column"),
        (Line2D([], [], marker="^", ms=5, **mark), "drag direction of each column (▲ up, ▼ down)"),
    ]
    key_legend(fig, key, loc="outside lower center", ncol=len(key), fontsize=8)
    return fig


def plot_trajectories(shape, truth, approx, T, vertex, picks, jumps=None, size=3.0, approx_name="TPS"):
    """Fig. 3: deformations with their approximations (top row), the trajectory of the starred point (below).

    Top row: the rest pose with the starred point ``vertex``, then one panel per handle displacement in
    ``picks``: the variational deformation (filled), the approximation ``approx`` (dashed outline), the
    starred point on both (filled: ground truth, hollow: approximation), and the handle's position as a
    coloured dot. Below, one column per trajectory in ``T``: its x and y components as images over the
    handle plane, the same coloured dots, and black crosses at the ground truth's jumps.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    truth : defop.analysis.trajectories.Trajectory
        The variational ground truth on a grid.
    approx : defop.analysis.trajectories.Trajectory
        The approximation drawn over it in the top row (the paper uses TPS).
    T : dict of str -> (ny, nx, 2) numpy array
        Trajectories T_x of ``vertex`` (columns), the ground truth first.
    vertex : int
        The starred point x.
    picks : (k,2) numpy array
        Handle displacements q − p of the top row (snapped to the nearest grid point).
    jumps : (j,2) numpy array, optional
        Handle displacements where the ground truth jumps (:func:`defop.analysis.trajectories.discontinuity_points`).
    approx_name : str
        The approximation's name in the key.

    Returns
    -------
    fig : matplotlib Figure
    """
    from matplotlib.lines import Line2D

    grid, mesh = truth.grid, shape.mesh
    colors = plt.cm.tab10(np.arange(len(picks)))
    snapped = np.array([grid.displacements[grid.nearest(d)] for d in picks])
    ncol = max(len(picks) + 1, len(T))
    fig = plt.figure(figsize=(size * ncol, 3.0 * size + 0.4))
    outer = fig.add_gridspec(2, 1, height_ratios=[0.7, 2], hspace=0.12)
    top = outer[0].subgridspec(1, ncol, wspace=0.08)
    ax = fig.add_subplot(top[0, 0])
    plot_mesh(ax, mesh.V, mesh.F, edges=True, edge_color="#00000018")
    plot_handles(ax, mesh.V, shape.handles, shape.moving, size=14)
    ax.plot(*mesh.V[vertex], "*", color="k", ms=13, zorder=12)
    ax.set_title("rest pose, starred point x", fontsize=9)
    for k, d in enumerate(snapped):
        ax = fig.add_subplot(top[0, k + 1])
        X, Y = truth.deformation(d), approx.deformation(d)
        plot_mesh(ax, mesh.V, mesh.F, X, edges=True, edge_color="#00000018")
        plot_outline(ax, mesh, Y, color="k", lw=1.0, ls="--")
        plot_handles(ax, X, shape.handles, shape.moving, size=14)
        ax.plot(*X[vertex], "*", color="k", ms=13, zorder=12)
        ax.plot(*Y[vertex], "*", mfc="none", mec="k", ms=13, zorder=12)
        ax.plot(*(grid.center + d), "o", color=colors[k], ms=8, mec="k", zorder=11)
        ax.set_title(f"q − p = ({d[0]:+.2f}, {d[1]:+.2f})", fontsize=9)
    bottom = outer[1].subgridspec(2, len(T) + 1, width_ratios=[1] * len(T) + [0.06], hspace=0.4, wspace=0.25)
    xe, ye = cell_edges(grid.xs), cell_edges(grid.ys)
    for c in range(2):
        vmax = max(np.abs(t[..., c]).max() for t in T.values())
        for k, (name, t) in enumerate(T.items()):
            ax = fig.add_subplot(bottom[c, k])
            im = ax.pcolormesh(xe, ye, t[..., c], cmap="coolwarm", vmin=-vmax, vmax=vmax, shading="flat")
            if k == 0 and jumps is not None and len(jumps):
                ax.plot(jumps[:, 0], jumps[:, 1], "kx", ms=4, clip_on=False)
            ax.scatter(*snapped.T, c=colors, s=30, edgecolors="k", clip_on=False, zorder=3)
            ax.set_xlim(xe[0], xe[-1]), ax.set_ylim(ye[0], ye[-1])
            ax.set_aspect("equal")
            ax.set_title(f"{readable(name)}: T_x, {'xy'[c]} component", fontsize=9)
            ax.set_xlabel("q_x − p_x")
            if k == 0:
                ax.set_ylabel("q_y − p_y")
        fig.colorbar(im, cax=fig.add_subplot(bottom[c, len(T)]), label=f"{'xy'[c]}-displacement of x")
    star = dict(marker="*", ls="none", ms=11, mec="k")
    dot = dict(marker="o", ls="none", mec="k", mew=0.5)
    key = [
        (patches.Patch(facecolor=FILL), "S-ARAP ground truth"),
        (Line2D([], [], color="k", lw=1.0, ls="--"), f"{approx_name} outline"),
        (Line2D([], [], mfc="k", **star), "starred point x (ground truth)"),
        (Line2D([], [], mfc="none", **star), "x under the approximation"),
        (Line2D([], [], mfc="0.7", ms=7, **dot), "handle position of a top panel (same colour below)"),
        (Line2D([], [], marker="x", color="k", ls="none", ms=5), "jump of the ground truth"),
        (Line2D([], [], mfc=MOVING, ms=5, **dot), "moving handle"),
        (Line2D([], [], mfc=FIXED, ms=5, **dot), "fixed handles"),
    ]
    key_legend(fig, key, loc="upper center", bbox_to_anchor=(0.5, 0.06), ncol=4)
    return fig


def plot_trajectories_3d(shape, truth, T, vertex, titles=None, n_poses=5, component=1):
    """Fig. 5: deformations of the bar (left) and one component of the starred point's trajectory as surfaces.

    Left, as in the paper: the ground truth at ``n_poses`` × ``n_poses`` handle positions spread over the grid,
    overlaid as outlines, each with its moving handle (a dot) and the starred point (a star). Right: for each
    trajectory in ``T``, its ``component`` (1: y, the paper's choice) as a surface over the handle plane, one colour
    scale for all.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    truth : defop.analysis.trajectories.Trajectory
    T : dict of str -> (ny, nx, 2) numpy array
        Trajectories of ``vertex``, the ground truth first.
    vertex : int
    titles : dict of str -> str, optional
        Panel title per entry of ``T`` (default: the readable name).
    n_poses : int
        Poses per axis of the left panel.
    component : {0, 1}

    Returns
    -------
    fig : matplotlib Figure
    """
    from matplotlib.lines import Line2D

    grid, mesh = truth.grid, shape.mesh
    c = "xy"[component]
    fig = plt.figure(figsize=(4.3 * (len(T) + 1), 4.4))
    spec = fig.add_gridspec(1, len(T) + 2, width_ratios=[1.15] + [1] * len(T) + [0.05], wspace=0.22)
    ax = fig.add_subplot(spec[0])
    pick = np.linspace(0, len(grid.xs) - 1, n_poses).round().astype(int)
    colours = plt.cm.viridis(np.linspace(0, 1, n_poses * n_poses))
    plot_mesh(ax, mesh.V, mesh.F, edges=False, color="0.85")
    for k, (i, j) in enumerate((i, j) for i in pick for j in pick):
        X = truth.X[i, j]
        plot_outline(ax, mesh, X, color=colours[k], lw=0.6, alpha=0.8)
        ax.plot(*X[vertex], "*", color=colours[k], ms=6, mec="k", mew=0.3)
        ax.plot(*(grid.center + grid.displacements[i, j]), "o", color=colours[k], ms=4, mec="k", mew=0.3)
    ax.set_axis_on()
    ax.set_xlabel("x"), ax.set_ylabel("y")
    ax.set_title(f"S-ARAP deformations at {n_poses * n_poses} handle positions", fontsize=9)
    ax.legend(
        [
            patches.Patch(color="0.85"),
            Line2D([], [], marker="o", color="0.4", ls="none", ms=4),
            Line2D([], [], marker="*", color="0.4", ls="none", ms=7),
        ],
        ["rest pose", "handle position", "starred point x"],
        fontsize=7,
        loc="upper left",
    )
    vmax = max(np.abs(t[..., component]).max() for t in T.values())
    gx, gy = np.meshgrid(grid.xs, grid.ys)
    surf = None
    for k, (name, t) in enumerate(T.items()):
        a = fig.add_subplot(spec[k + 1], projection="3d")
        surf = a.plot_surface(
            gx,
            gy,
            t[..., component],
            cmap="coolwarm",
            vmin=-vmax,
            vmax=vmax,
            lw=0.2,
            edgecolor="0.3",
            rstride=1,
            cstride=1,
        )
        a.set_zlim(-vmax, vmax)
        a.set_xlabel("q_x − p_x", fontsize=7, labelpad=4), a.set_ylabel("q_y − p_y", fontsize=7, labelpad=9)
        a.set_zlabel(f"T_{c}", fontsize=8, labelpad=5)
        a.tick_params(labelsize=6, pad=0)
        for axis in (a.xaxis, a.yaxis, a.zaxis):
            axis.set_major_locator(plt.MaxNLocator(3))
        a.set_title((titles or {}).get(name, readable(name)), fontsize=9, y=0.98)
        a.view_init(elev=28, azim=-60)
        a.set_box_aspect(None, zoom=0.88)
    fig.colorbar(surf, cax=fig.add_subplot(spec[-1]), label=f"T_{c}: {c}-displacement of x")
    fig.suptitle(f"Fig. 5: the trajectory of the starred point x, {c} component T_{c}, over the handle plane", y=0.99)
    return fig


def plot_path_trajectories(t, T, reference="ground truth", size=4.2):
    """Trajectories of one point along a handle path in 3D (Figs. 3 and 5 for volumetric shapes).

    Left: each trajectory T_x(t) = D(x, Q(t)) − x as a curve in space (the reference solid, the others dashed).
    Right: each trajectory's distance to the reference along the path.

    Parameters
    ----------
    t : (k,) numpy array
        The path parameter of each configuration Q(t).
    T : dict of str -> (k,3) numpy array
        Trajectories, ``reference`` among them.
    reference : str
    size : float
        Inches per panel.

    Returns
    -------
    fig : matplotlib Figure
    """
    t = np.asarray(t, float)
    if reference not in T or any(np.shape(v) != (len(t), 3) for v in T.values()):
        raise ValueError(f"T must map names (with {reference!r}) to (k,3) trajectories, k = {len(t)}")
    fig = plt.figure(figsize=(2.3 * size, size))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    err = fig.add_subplot(1, 2, 2)
    ref = np.asarray(T[reference])
    for name, D in T.items():
        D = np.asarray(D)
        style = dict(color="k", lw=2.2) if name == reference else dict(ls="--", marker="o", ms=3)
        (line,) = ax.plot(D[:, 0], D[:, 1], D[:, 2], label=readable(name), **style)
        if name != reference:
            err.plot(t, np.linalg.norm(D - ref, axis=1), "o-", ms=3, color=line.get_color(), label=readable(name))
    ax.scatter(*ref[0], color="k", s=12)
    ax.set_xlabel("T_x"), ax.set_ylabel("T_y"), ax.set_zlabel("T_z")
    ax.set_title("trajectory of the point x in space", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    err.set_xlabel("path parameter t (twist and shift grow with t)")
    err.set_ylabel(f"|T − T {reference}|")
    err.set_title(f"distance to the {reference} along the path", fontsize=9)
    err.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_error_over_m(counts, error, ylabel, sizes=None):
    """Held-out error against the number of samples m for each handle basis, log-log (Fig. 8).

    Parameters
    ----------
    counts : (c,) sequence of int
    error : dict of str -> (c,) numpy array
        Error per basis (NaN where the basis needs more samples).
    ylabel : str
    sizes : dict of str -> int, optional
        |Ψ| of the polynomial bases: a dotted line at the fewest samples each needs.

    Returns
    -------
    fig : matplotlib Figure
    """
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for b, e in error.items():
        (line,) = ax.loglog(
            counts, e, "o-", label=readable(b) + (f" (|Ψ| = {sizes[b]})" if sizes and b in sizes else "")
        )
        if sizes and b in sizes:
            ax.axvline(sizes[b], color=line.get_color(), ls=":", lw=1)
    ax.set_xticks(list(counts), [str(c) for c in counts], minor=False)
    ax.set_xticks([], minor=True)
    ax.set_xlabel("number of samples m")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
