"""Fig. 6: deformations under different energies, zooms coloured by corner-angle change, and the solver race."""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from .draw import FILL, FLIP, MOVING, key_legend, plot_deformation, plot_handle_zoom, plot_outline

__all__ = ["plot_energy_comparison", "plot_energies_figure", "plot_convergence"]


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
