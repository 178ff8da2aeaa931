"""Operators against their ground truths: the handle bases side by side (Figs. 7-9) and the model gallery (Fig. 11)."""

from __future__ import annotations

import numpy as np
from matplotlib import patches
from matplotlib import pyplot as plt

from .draw import FLIP, figure_key, plot_deformation, plot_handles, plot_mesh, plot_outline, readable

__all__ = ["plot_bases_grid", "plot_gallery"]


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
            note = _operator_panel(ax, shape, None if D[name] is None else D[name][c], X_true[c], note)
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


def _operator_panel(ax, shape, X, X_true, note):
    """One panel of :func:`plot_bases_grid`: D(·, Q) filled with the ground truth outlined, or "not fitted" (with the
    note) where ``X`` is None. Returns the note still to print under the panel."""
    if X is None:
        ax.text(
            0.5, 0.5, "not fitted\n" + note, transform=ax.transAxes, ha="center", va="center", fontsize=8, color="0.4"
        )
        return ""
    plot_mesh(ax, shape.mesh.V, shape.mesh.F, X, edges=False)
    plot_handles(ax, X, shape.handles, shape.moving, size=12)
    plot_outline(ax, shape.mesh, X_true, lw=0.8)
    return note


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
