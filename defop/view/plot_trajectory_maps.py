"""Trajectories of a point over the handle plane or along a handle path (Figs. 3, 5 and 10), and the error
against the number of samples (Fig. 8)."""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from .draw import (
    FILL,
    FIXED,
    MOVING,
    cell_edges,
    key_legend,
    plot_deformation,
    plot_handles,
    plot_mesh,
    plot_outline,
    readable,
)

__all__ = [
    "plot_local_vs_global",
    "plot_trajectories",
    "plot_trajectories_3d",
    "plot_path_trajectories",
    "plot_error_over_m",
]


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

    nrow, ncol = len(show), len(rows)
    fig, axes = plt.subplots(
        nrow,
        ncol + 2,
        figsize=(4.0 * ncol + 9, 3.6 * nrow),
        layout="constrained",
        squeeze=False,
        gridspec_kw={"width_ratios": [1] * ncol + [1.1, 1.25]},
    )
    vmax = max(np.abs(r.of(vertex)[..., 1]).max() for r in runs.values())
    for a, (k, label) in zip(axes, show.items()):
        r = runs[k]
        for ax, i in zip(a, rows):
            where = f"q − p = ({grid.xs[col]:+.2f}, {grid.ys[i]:+.3f})"
            plot_deformation(ax, shape, r.X[i, col], edges=False, title=f"{label}\n{where}")
            ax.plot(*r.X[i, col, vertex], "k*", ms=9)
            ax.set_xlim(-0.1, 1.05), ax.set_ylim(-0.45, 0.65)
        drag = None if not k.startswith("local") else (np.arange(len(grid.xs)) % 2 == 0) == first_up
        im = _star_heat_map(a[ncol], grid, r.of(vertex)[..., 1], vmax, col, rows, jumps[k], drag, label)
    fig.colorbar(im, ax=axes[:, ncol], shrink=0.85, location="right", label="T_y: y-displacement of the star")
    _along_column(axes[:, ncol + 1], grid, runs, vertex, col, nrow)
    key = _local_global_key()
    key_legend(fig, key, loc="outside lower center", ncol=len(key), fontsize=8)
    return fig


def _local_global_key():
    """The (artist, text) pairs of Fig. 10's key."""
    from matplotlib.lines import Line2D

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
    return key


def _star_heat_map(hm, grid, Ty, vmax, col, rows, jumps, drag, label):
    """Fig. 10's heat map of T_y over the handle plane: the positions shown (○), the jumps (×), the drags (▲/▼).

    ``drag`` is None or a bool per column (True: dragged up). Returns the colour-mapped mesh (for the colour bar).
    """
    xe, ye = cell_edges(grid.xs), cell_edges(grid.ys)
    im = hm.pcolormesh(xe, ye, Ty, cmap="coolwarm", vmin=-vmax, vmax=vmax, shading="flat")
    hm.plot(np.full(len(rows), grid.xs[col]), grid.ys[rows], "ko", mfc="none", ms=7, clip_on=False, zorder=4)
    hm.plot(grid.xs, jumps, "kx", ms=6, zorder=4)
    if drag is not None:
        for j, u in enumerate(drag):
            hm.plot(grid.xs[j], ye[-1], "^" if u else "v", color="k", ms=4, clip_on=False, zorder=4)
    hm.set_xlim(xe[0], xe[-1]), hm.set_ylim(ye[0], ye[-1])
    hm.set_title(f"{label}: T_y of the star", fontsize=9, pad=10)
    hm.set_xlabel("q_x − p_x"), hm.set_ylabel("q_y − p_y")
    return im


def _along_column(right, grid, runs, vertex, col, nrow):
    """Fig. 10's right-hand plots: T_y of the star and (with two rows) the energy along the grid column ``col``."""
    styles = {k: "o-" if k == "global" else ".--" for k in runs if k != "rest"}
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

    grid = truth.grid
    colors = plt.cm.tab10(np.arange(len(picks)))
    snapped = np.array([grid.displacements[grid.nearest(d)] for d in picks])
    ncol = max(len(picks) + 1, len(T))
    fig = plt.figure(figsize=(size * ncol, 3.0 * size + 0.4))
    outer = fig.add_gridspec(2, 1, height_ratios=[0.7, 2], hspace=0.12)
    _poses_row(fig, outer[0].subgridspec(1, ncol, wspace=0.08), shape, truth, approx, vertex, snapped, colors)
    bottom = outer[1].subgridspec(2, len(T) + 1, width_ratios=[1] * len(T) + [0.06], hspace=0.4, wspace=0.25)
    _component_maps(fig, bottom, grid, T, jumps, snapped, colors)
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


def _poses_row(fig, top, shape, truth, approx, vertex, snapped, colors):
    """Fig. 3's top row: the rest pose, then the ground truth (filled) and the approximation (dashed) at each
    handle displacement of ``snapped``, the starred point on both and the handle's position as a coloured dot."""
    grid, mesh = truth.grid, shape.mesh
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


def _component_maps(fig, bottom, grid, T, jumps, snapped, colors):
    """Fig. 3's lower rows: each trajectory's x and y components over the handle plane, one colour bar per row."""
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

    grid = truth.grid
    c = "xy"[component]
    fig = plt.figure(figsize=(4.3 * (len(T) + 1), 4.4))
    spec = fig.add_gridspec(1, len(T) + 2, width_ratios=[1.15] + [1] * len(T) + [0.05], wspace=0.22)
    _overlaid_poses(fig.add_subplot(spec[0]), shape, truth, vertex, n_poses)
    vmax = max(np.abs(t[..., component]).max() for t in T.values())
    gx, gy = np.meshgrid(grid.xs, grid.ys)
    surf = None
    for k, (name, t) in enumerate(T.items()):
        a = fig.add_subplot(spec[k + 1], projection="3d")
        surf = _component_surface(a, gx, gy, t[..., component], vmax, c, (titles or {}).get(name, readable(name)))
    fig.colorbar(surf, cax=fig.add_subplot(spec[-1]), label=f"T_{c}: {c}-displacement of x")
    fig.suptitle(f"Fig. 5: the trajectory of the starred point x, {c} component T_{c}, over the handle plane", y=0.99)
    return fig


def _overlaid_poses(ax, shape, truth, vertex, n_poses):
    """Fig. 5's left panel: the ground truth at ``n_poses`` × ``n_poses`` handle positions, overlaid as outlines,
    each with its handle position (a dot) and the starred point (a star)."""
    from matplotlib.lines import Line2D

    grid, mesh = truth.grid, shape.mesh
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


def _component_surface(a, gx, gy, values, vmax, c, title):
    """One component ``c`` ("x" or "y") of a trajectory as a surface over the handle plane on the 3D axes ``a``."""
    surf = a.plot_surface(
        gx,
        gy,
        values,
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
    a.set_title(title, fontsize=9, y=0.98)
    a.view_init(elev=28, azim=-60)
    a.set_box_aspect(None, zoom=0.88)
    return surf


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
