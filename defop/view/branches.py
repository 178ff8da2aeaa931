"""Pictures of a multi-valued operator (notebook 15): two minima and the saddle between them, the energy profile
of the mountain pass, the branches' domains in the handle plane, the hysteresis loop of ``follow`` beside the
solver's, errors per frame."""

from __future__ import annotations

import warnings

import numpy as np
from matplotlib import pyplot as plt

from .plot import plot_deformation

BRANCH_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")


def plot_minima(shape, X, titles, energies, size=3.0):
    """Deformations side by side (two minima and the saddle between them) and their energies.

    Parameters
    ----------
    shape : Shape
    X : list of (n_vertices, 2) numpy arrays
    titles : list of str
    energies : list of float
        E of each deformation.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, axes = plt.subplots(1, len(X) + 1, figsize=(size * (len(X) + 1), size * 0.9))
    for ax, x, t in zip(axes, X, titles):
        plot_deformation(ax, shape, x, title=t)
    axes[-1].bar(range(len(X)), energies, color=[BRANCH_COLORS[0], "0.6", BRANCH_COLORS[1]][: len(X)])
    axes[-1].set_xticks(range(len(X)), [t.split(" (")[0] for t in titles], fontsize=7)
    axes[-1].set_ylabel("E (Eq. 11)")
    axes[-1].set_title("energy")
    fig.tight_layout()
    return fig


def plot_pass(profiles, saddles, probes, ts, size=3.6):
    """The mountain pass between two minima (:func:`defop.analysis.saddle.mountain_pass`) and probes at its saddle.

    Parameters
    ----------
    profiles : list of Profile
        Each climb from one minimum (E⋆ against the pinned vertex's height), coloured by branch.
    saddles : list of Saddle
        The critical point at the top of each profile (a star).
    probes : dict of str -> (2, k) numpy array
        E(X ± tD) − E(X) at the saddle per direction name (:func:`defop.analysis.saddle.probe`).
    ts : (k,) numpy array
        The steps t of the probes, as a fraction of the bbox diagonal.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(size * 2.3, size))
    for b, (p, s) in enumerate(zip(profiles, saddles)):
        color = BRANCH_COLORS[b % len(BRANCH_COLORS)]
        y, E = p.pins[:, 1], p.energies
        if s is not None:
            y, E = np.append(y[: p.top + 1], s.pin[1]), np.append(E[: p.top + 1], s.energy)
            ax.plot(s.pin[1], s.energy, "*", color=color, ms=12, mec="k", mew=0.5)
        ax.plot(y, E, "o-", color=color, ms=3, lw=1.2, label=f"climb from branch {b}")
        ax.plot(y[0], E[0], "s", color=color, ms=6)
    ax.set_xlabel("height of the pinned mid-bar point")
    ax.set_ylabel("E* (Eq. 11)")
    ax.set_title("the pass: pinned minima, saddles (stars)")
    ax.legend(fontsize=7)
    styles = ("-", "--", ":", "-.")
    for (name, dE), ls in zip(probes.items(), styles):
        for row, sign in zip(dE, ("+", "−")):
            bx.loglog(ts, np.abs(row), ls, marker="o" if sign == "+" else "x", ms=3, lw=1, label=f"{name} ({sign}t)")
            neg = row < 0
            bx.loglog(ts[neg], np.abs(row[neg]), "v", color="k", ms=4, mfc="none")
    bx.set_xlabel("t / bbox diagonal")
    bx.set_ylabel("|E(X ± tD) − E(X)|  (▽: below E(X))")
    bx.set_title("at the saddle")
    bx.legend(fontsize=6)
    fig.tight_layout()
    return fig


def plot_domains(
    samples_xy, branches, grid_xy, exists, path_xy=None, size=3.6, absent=None, edges=None, axes=None, title=""
):
    """The branches in the handle plane: samples where each has a minimum, where it is certified absent, its edge,
    and its estimated domain.

    Parameters
    ----------
    samples_xy : (m, 2) numpy array
        Handle displacements of the samples.
    branches : list of (label, (k,) sample indices)
    grid_xy : (gy, gx, 2) numpy array
        A fine grid of handle displacements.
    exists : (gy, gx, B) numpy bool array
        The operator's domain estimate on the grid.
    path_xy : (k, 2) numpy array, optional
    absent : list of (a,) int arrays, optional
        Per branch: the samples certified absent (a solve from the branch left it), drawn as crosses.
    edges : list of (s, 2, 2) numpy arrays, optional
        Per branch: the segments of its edge (bisected fold points), in displacements.
    axes : sequence of matplotlib Axes, optional
        One per branch (default: a new figure with one row).
    title : str
        Prefix of each panel's title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    B = len(branches)
    if axes is None:
        fig, ax_row = plt.subplots(1, B, figsize=(size * B, size), squeeze=False)
        axes = ax_row[0]
    fig = axes[0].figure
    for b, (ax, (label, idx)) in enumerate(zip(axes, branches)):
        color = BRANCH_COLORS[b % len(BRANCH_COLORS)]
        ax.contourf(
            grid_xy[..., 0], grid_xy[..., 1], exists[..., b].astype(float), levels=[0.5, 1.5], colors=[color], alpha=0.2
        )
        ax.contour(grid_xy[..., 0], grid_xy[..., 1], exists[..., b].astype(float), levels=[0.5], colors=[color])
        ax.plot(samples_xy[:, 0], samples_xy[:, 1], ".", color="0.75", ms=3)
        ax.plot(samples_xy[idx, 0], samples_xy[idx, 1], "o", color=color, ms=3.5)
        if absent is not None:
            ax.plot(samples_xy[absent[b], 0], samples_xy[absent[b], 1], "x", color="k", ms=4.5, mew=1.2)
        if edges is not None:
            for seg in edges[b]:
                ax.plot(seg[:, 0], seg[:, 1], "-", color="k", lw=1.4)
        if path_xy is not None:
            ax.plot(path_xy[:, 0], path_xy[:, 1], "k--", lw=0.8)
        ax.set_title(f"{title}branch {label}: {len(idx)} samples" + ("" if absent is None else f", {len(absent[b])} ✕"))
        ax.set_xlabel("q_x − p_x")
        ax.set_aspect("equal")
    axes[0].set_ylabel("q_y − p_y")
    fig.tight_layout()
    return fig


def plot_hysteresis(t, solver, operator, labels, errors, names=("solver (warm-started)", "follow (operator)")):
    """The hysteresis loop of a point along a there-and-back path, solver and operator side by side, and errors.

    Parameters
    ----------
    t : (k,) numpy array
        The path parameter shown on the x axis (e.g. q_y − p_y).
    solver, operator : (k,) numpy arrays
        The point's coordinate per frame.
    labels : (k,) numpy int array
        ``follow``'s branch per frame (colours the operator's curve).
    errors : dict of str -> (k,) numpy arrays
        Per-frame errors (max vertex distance / bbox diagonal).

    Returns
    -------
    matplotlib.figure.Figure
    """
    k = len(t)
    half = k // 2
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    for ax, y, name in zip(axes[:2], (solver, operator), names):
        ax.plot(t[: half + 1], y[: half + 1], "-", color="0.3", lw=1, label="out")
        ax.plot(t[half:], y[half:], "--", color="0.3", lw=1, label="back")
        ax.set_title(name)
        ax.set_xlabel("q_y − p_y along the path")
    for b in np.unique(labels):
        on = labels == b
        axes[1].plot(
            t[on], operator[on], ".", ms=3, color=BRANCH_COLORS[int(b) % len(BRANCH_COLORS)], label=f"branch {int(b)}"
        )
    axes[0].set_ylabel("y of the marked point")
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=7)
    for name, e in errors.items():
        axes[2].semilogy(np.arange(k), np.maximum(e, 1e-16), lw=1, label=name)
    axes[2].set_xlabel("frame")
    axes[2].set_ylabel("error / bbox diagonal")
    axes[2].legend(fontsize=7)
    axes[2].set_title("error against the solver")
    fig.tight_layout()
    return fig


def case_domains(case, n=61):
    """The inputs of :func:`plot_domains` for a :class:`defop.analysis.branches.Case` with certified branches: a dict
    of samples_xy, branches, grid_xy, exists (on an n × n grid over the samples' box), path_xy, absent, edges."""
    B, bop, P = case.branches, case.operator, case.shape.P_moving[0]
    disp = B.samples[: B.grid, 0, :2] - P[:2]
    lo, hi = disp.min(axis=0), disp.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    grid_xy = np.stack([gx, gy], axis=-1)
    Qg = np.repeat(case.shape.P_moving[None], n * n, axis=0)
    Qg[:, 0, :2] += grid_xy.reshape(-1, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exists = bop.exists(Qg).reshape(n, n, -1)
    return {
        "samples_xy": disp,
        "branches": [(b.label, b.samples[b.samples < B.grid]) for b in B.branches],
        "grid_xy": grid_xy,
        "exists": exists,
        "path_xy": case.comparison.Qs[:, 0, :2] - P[:2],
        "absent": [b.absent for b in B.branches],
        "edges": [np.asarray(b.segments)[:, :, 0, :2] - P[:2] for b in B.branches],
    }


def plot_case_domains(cases, titles, size=3.4):
    """:func:`plot_domains` of several certified cases, one row each (:func:`case_domains`)."""
    rows = [case_domains(c) for c in cases]
    B = max(len(r["branches"]) for r in rows)
    fig, axes = plt.subplots(len(rows), B, figsize=(size * B, size * len(rows)), squeeze=False)
    for r, ax_row, title in zip(rows, axes, titles):
        plot_domains(**r, axes=ax_row[: len(r["branches"])], title=title)
    fig.tight_layout()
    return fig
