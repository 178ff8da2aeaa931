"""Figures that explain themselves: every figure of the lessons is drawn with no two texts overlapping.

Each test calls the plotting function a notebook calls, on small synthetic data of the same shapes (the notebooks
also assert it on their real figures, ``dop.view.labels.text_overlaps``), and checks the texts' window extents after
``fig.canvas.draw()``.
"""

from __future__ import annotations

import types

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import defop as dop  # noqa: E402
from defop.analysis.trajectories import Trajectory, handle_grid  # noqa: E402
from defop.view import labels, plot, plot_peers  # noqa: E402


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar")


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


def _bend(shape, q):
    """A smooth made-up deformation of the bar that follows its moving handle to q (not a solve)."""
    V = shape.mesh.V
    d = np.asarray(q, float) - shape.P_moving[0]
    t = (V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0])
    return V + t[:, None] ** 2 * d


class _Op:
    def __init__(self, shape, kind="tps", energy="sarap", m=17, wobble=0.0):
        self.shape, self.energy, self.n_samples, self.wobble = shape, energy, m, wobble
        self.handle_basis = types.SimpleNamespace(kind=kind)

    def __call__(self, Q):
        Q = np.asarray(Q, float)
        if Q.ndim == 2:
            return _bend(self.shape, Q[0]) + self.wobble
        return np.stack([self(q) for q in Q])


def _trajectory(shape, grid, kind="global", shift=0.0):
    X = np.stack([[_bend(shape, grid.center + d) + shift for d in row] for row in grid.displacements])
    energy = np.linspace(0.005, 0.012, grid.size).reshape(grid.shape)
    return Trajectory(grid, X, shape.mesh.V, kind, energy=energy)


def _no_overlap(fig):
    found = labels.text_overlaps(fig)
    assert not found, "texts overlap: " + "; ".join(f"{a!r} / {b!r} ({area:.0f} px²)" for a, b, area in found)


# the two panels of peers_pareto.png as measured (aleph, octopus): names, (8a)/n over N = 50, median frame seconds
PEERS = {
    "aleph": [
        ("MLS similarity", 1.14e-05, 34.2e-6),
        ("MLS rigid", 1.05e-05, 78.5e-6),
        ("TPS warp (Bookstein)", 1.13e-05, 15.2e-6),
        ("BBW + LBS", 1.06e-05, 17.1e-6),
        ("biharmonic coordinates", 1.24e-05, 15.1e-6),
        ("libigl ARAP, 10 it.", 4.69e-06, 9.52e-3),
        ("libigl ARAP, 50 it.", 1.14e-06, 47.1e-3),
        ("defop TPS-500", 1.58e-06, 658e-6),
        ("defop TPS-500, compressed", 1.58e-06, 63.2e-6),
    ],
    "octopus": [
        ("MLS similarity", 6.81e-05, 57.3e-6),
        ("MLS rigid", 6.79e-05, 116e-6),
        ("TPS warp (Bookstein)", 7.94e-05, 22.8e-6),
        ("BBW + LBS", 8.11e-05, 24.6e-6),
        ("biharmonic coordinates", 6.59e-05, 22.1e-6),
        ("libigl ARAP, 10 it.", 3.63e-05, 12.6e-3),
        ("libigl ARAP, 50 it.", 2.23e-05, 64.8e-3),
        ("defop TPS-1000", 4.09e-06, 2.33e-3),
        ("defop TPS-1000, compressed", 4.09e-06, 88.9e-6),
    ],
}


def _scores(rows):
    return [types.SimpleNamespace(name=n, error=e, frame_median=t) for n, e, t in rows]


def test_the_overlap_check_finds_overlapping_texts():
    fig, ax = plt.subplots()
    ax.text(0.5, 0.5, "one label")
    ax.text(0.52, 0.5, "another label")
    assert labels.text_overlaps(fig)


def test_peers_pareto_labels_never_overlap():
    fig, axes = plt.subplots(1, 2, figsize=(12.4, 4.6))
    for ax, (name, rows) in zip(axes, PEERS.items()):
        plot_peers.pareto_plot(ax, _scores(rows), title=f"{name}: error against time per frame", n_samples=50)
    fig.tight_layout()
    _no_overlap(fig)
    assert "N = 50" in axes[0].get_ylabel()
    # every method has its label, and DefOp is keyed
    texts = {t.get_text() for t in axes[0].texts}
    assert texts == {n for n, *_ in PEERS["aleph"]}
    assert "DefOp" in [t.get_text() for t in axes[0].get_legend().get_texts()]


@settings(max_examples=15, deadline=None)
@given(st.lists(st.tuples(st.floats(-6, -1), st.floats(-7, -3)), min_size=2, max_size=10))
def test_placed_labels_overlap_no_other_label(points):
    fig, ax = plt.subplots(figsize=(6, 4))
    t, e = 10.0 ** np.array(points).T
    ax.scatter(t, e)
    ax.set_xscale("log"), ax.set_yscale("log")
    ax.set_xlim(t.min() / 5, t.max() * 5), ax.set_ylim(e.min() / 2, e.max() * 2)
    anns = labels.place_labels(ax, t, e, [f"method number {i}" for i in range(len(t))])
    renderer = fig.canvas.get_renderer()
    boxes = [labels.text_extent(a, renderer) for a in anns]
    # with room enough (at most 10 short labels on a 6 x 4 inch plot) no two placed labels overlap
    for i in range(len(boxes)):
        for j in range(i):
            assert (
                labels._overlap(
                    (boxes[i].x0, boxes[i].y0, boxes[i].x1, boxes[i].y1),
                    (boxes[j].x0, boxes[j].y0, boxes[j].x1, boxes[j].y1),
                )
                <= 1.0
            )


def test_fig09_bases_grid(bar):
    Q = bar.P_moving[None] + np.array([[[-0.1, 0.2]], [[0.1, -0.2]], [[0.2, 0.1]], [[-0.2, -0.1]]])
    X = np.stack([_bend(bar, q[0]) for q in Q])
    rows = {"linear, m = 25": _Op(bar, "linear", wobble=0.01), "quadratic, m = 25": None, "TPS, m = 25": _Op(bar)}
    notes = {r: ["m < |Ψ| = 66" if op is None else f"{1e-7 * (i + 1):.1e}" for i in range(4)] for r, op in rows.items()}
    fig = plot.plot_bases_grid(bar, Q, X, rows, [f"held-out #{i}\ntip turns {10 * i}°" for i in range(4)], notes=notes)
    fig.suptitle("Fig. 9: operators (filled) against the ground truth (outline)", y=1.04)
    _no_overlap(fig)


def test_fig11_gallery(bar):
    q = bar.P_moving + [0.1, 0.3]
    panels = [(bar, _Op(bar, m=m, energy=e), q, _bend(bar, q[0])) for m, e in ((17, "sarap"), (40, "arap"))]
    fig = plot.plot_gallery(panels, {"bar": 0.012})
    _no_overlap(fig)
    titles = " ".join(ax.get_title() for ax in fig.axes)
    assert "S-ARAP" in titles and "ARAP" in titles and "sarap" not in titles and "(tps" not in titles


def test_fig10_local_vs_global(bar):
    grid = handle_grid(bar.P_moving[0], 0.3, 7)
    runs = {
        "global": _trajectory(bar, grid),
        "local, dragging up": _trajectory(bar, grid, shift=0.01),
        "local, dragging down": _trajectory(bar, grid, shift=-0.01),
    }
    jumps = {k: np.where(np.arange(7) < 3, 0.0, np.nan) for k in runs}
    show = {"global": "global", "local, dragging up": "local (dragging up)"}
    fig = plot.plot_local_vs_global(bar, grid, runs, jumps, 10, 0, [0, 2, 3, 6], show)
    fig.suptitle("Fig. 10: the bar (S-ARAP), global (top) against local (bottom) optima")
    _no_overlap(fig)
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert bars and all(ax.get_ylabel() for ax in bars), "the colour bar is labelled"


def test_fig06_energies(bar):
    rng = np.random.default_rng(0)
    results = {
        e: types.SimpleNamespace(X=_bend(bar, bar.P_moving[0] + [0.1 * k, 0.2]))
        for k, e in enumerate(("arap", "sarap"))
    }
    race = {
        name: types.SimpleNamespace(
            energy_history=1 + np.sort(rng.random(50))[::-1] * 10.0**-k, time_history=np.linspace(1e-3, 1, 50)
        )
        for k, name in enumerate(("projected Newton", "L-BFGS"))
    }
    titles = {"arap": "ARAP (Eq. 10)", "sarap": "S-ARAP (Eq. 11)"}
    fig = plot.plot_energies_figure(bar, results, titles, bar.moving_handles[0], race)
    _no_overlap(fig)
    cbar = [ax for ax in fig.findobj(matplotlib.axes.Axes) if "corner-angle" in ax.get_ylabel()]
    assert len(cbar) == 1 and cbar[0].get_ylim()[1] >= 90, "one labelled colour bar, up to 90° at least"


def test_fig03_and_fig05_trajectories(bar):
    grid = handle_grid(bar.P_moving[0], 0.3, 7)
    truth, approx = _trajectory(bar, grid), _trajectory(bar, grid, shift=0.01)
    x = int(np.argmin(np.linalg.norm(bar.mesh.V - [0.5, 0.1], axis=1)))
    T = {"ground truth": truth.of(x), "linear": approx.of(x), "quadratic": approx.of(x), "tps": approx.of(x)}
    picks = np.array([[-0.25, -0.05], [-0.25, 0.05], [0.0, 0.25], [0.2, 0.0]])
    fig = plot.plot_trajectories(bar, truth, approx, T, x, picks, jumps=np.array([[-0.3, 0.0], [-0.2, 0.0]]))
    fig.suptitle("Fig. 3: S-ARAP (filled) and TPS (dashed) at coloured handle positions")
    _no_overlap(fig)
    fig = plot.plot_trajectories_3d(bar, truth, T, x, {"ground truth": "ground truth (S-ARAP)", "tps": "TPS"})
    _no_overlap(fig)
    assert any("T_y" in ax.get_ylabel() for ax in fig.axes), "the colour scale says it shows T_y"
