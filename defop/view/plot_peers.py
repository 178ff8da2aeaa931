"""Figures of notebooks 12 and 13: DefOp against its peers, and image warping (matplotlib)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

from ..analysis.compare import pareto_front
from .plot import key_legend

FILL, FLIP, HANDLE = "#9ecae1", "#e31a1c", "#d95f02"


def pareto_plot(ax, scores, title=None, highlight="defop", n_samples=None):
    """(8a)/n over N held-out samples against median frame time on log axes, with the Pareto front.

    Each method is a point labelled with its name, placed clear of the other labels and points
    (:func:`defop.view.labels.place_labels`, with a leader line where a label had to move away).

    Parameters
    ----------
    ax : matplotlib Axes
    scores : list of defop.analysis.compare.Score
    title : str, optional
    highlight : str
        Methods whose name starts with this are drawn as red stars (DefOp), the others as blue dots.
    n_samples : int, optional
        N, the number of held-out samples the errors sum over (stated in the axis label).
    """
    from .labels import place_labels

    t = np.array([s.frame_median for s in scores])
    e = np.array([s.error for s in scores])
    ours = np.array([s.name.startswith(highlight) for s in scores])
    front = pareto_front(t, e)
    ax.step(t[front], e[front], where="post", color="0.6", lw=1, zorder=1, label="Pareto front")
    ax.scatter(t[~ours], e[~ours], s=40, zorder=3, color="#3182bd", marker="o", label="closed forms and ARAP")
    ax.scatter(t[ours], e[ours], s=70, zorder=3, color=FLIP, marker="*", label="DefOp")
    ax.set_xscale("log")
    ax.set_yscale("log")
    # room for the labels: half a decade beyond the points on each side
    ax.set_xlim(t.min() / 3.0, t.max() * 6.0)
    ax.set_ylim(e.min() / 1.6, e.max() * 1.6)
    ax.set_xlabel("time per frame (s, median, 1 BLAS thread)")
    n = "N" if n_samples is None else f"N = {n_samples}"
    ax.set_ylabel(f"(8a)/n over {n} held-out samples\n(against S-ARAP)")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    if title:
        ax.set_title(title)
    legend = ax.legend(loc="best", fontsize=7)
    place_labels(ax, t, e, [s.name for s in scores], fontsize=7, avoid=[legend])


def draw_deformation(ax, mesh, X, handles=None, reference=None, title=None):
    """A deformed mesh, flipped triangles in red, handles as dots and a reference outline (e.g. ground truth).

    Parameters
    ----------
    ax : matplotlib Axes
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array
    handles : (h,2) numpy array, optional
        Handle targets.
    reference : (n,2) numpy array, optional
        Positions whose boundary is drawn as a black outline.
    title : str, optional
    """
    flipped = mesh.flipped(X)
    colors = np.where(flipped, FLIP, FILL)
    ax.add_collection(PolyCollection(X[mesh.F], facecolors=colors, edgecolors="none", zorder=1))
    ax.autoscale_view()
    if reference is not None:
        for loop in mesh.boundary_loops():
            ring = reference[np.append(loop, loop[0])]
            ax.plot(ring[:, 0], ring[:, 1], color="k", lw=0.6, zorder=2)
    if handles is not None:
        ax.scatter(handles[:, 0], handles[:, 1], s=14, color=HANDLE, zorder=3)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=8)


def deformation_key(fig, y=0.0):
    """A key below a figure of :func:`draw_deformation` panels: fill, flips, ground-truth outline, handles.

    Returns
    -------
    legend : matplotlib Legend
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    items = [
        (Patch(color=FILL), "the method's deformation"),
        (Patch(color=FLIP), "flipped triangle"),
        (Line2D([], [], color="k", lw=0.8), "S-ARAP ground truth (outline)"),
        (Line2D([], [], marker="o", color=HANDLE, ls="none", ms=5), "handle target"),
    ]
    return key_legend(fig, items, loc="upper center", bbox_to_anchor=(0.5, y), ncol=len(items))


def coat_picture(mask, period=20.0):
    """A procedural picture: a smooth colour field with a grid every ``period`` pixels, white outside ``mask``.

    Parameters
    ----------
    mask : (H,W) bool numpy array
        True on the shape.
    period : float

    Returns
    -------
    image : (H,W,3) float numpy array in [0,1]
    """
    H, W = mask.shape
    y, x = np.mgrid[0:H, 0:W].astype(float)
    colour = np.stack(
        [0.5 + 0.5 * np.sin(x / 40), 0.5 + 0.5 * np.sin(y / 30 + 1), 0.5 + 0.5 * np.cos((x + y) / 50)], axis=-1
    )
    grid = ((x % period) < 2) | ((y % period) < 2)
    return np.where(mask[..., None], np.where(grid[..., None], 0.1, colour), 1.0)


def image_row(images, titles, size=3.2):
    """Pictures side by side.

    Parameters
    ----------
    images : list of (H,W,3) numpy array
    titles : list of str
    size : float

    Returns
    -------
    fig : matplotlib Figure
    """
    fig, axes = plt.subplots(1, len(images), figsize=(size * len(images), size * 0.85))
    for ax, im, t in zip(np.atleast_1d(axes), images, titles):
        ax.imshow(np.clip(im, 0, 1), interpolation="nearest")
        ax.set_title(t, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    return fig
