"""defop.view.plot: the Fig. 3 layout (deformations with their approximations, trajectories of the starred point)."""

import numpy as np

import defop as dop


def test_plot_trajectories_marks_the_starred_point_and_every_pick():
    shape = dop.shapes.load("bar", n_vertices=250)
    grid = dop.analysis.trajectories.handle_grid(shape.P_moving[0], 0.2, 5)
    V = shape.mesh.V
    d = grid.displacements  # (5,5,2)
    w = V[:, :1] / V[:, 0].max()  # each vertex follows the handle in proportion to x
    X = V[None, None] + w[None, None] * d[:, :, None, :]
    truth = dop.analysis.trajectories.Trajectory(grid=grid, X=X, rest=V, kind="global")
    approx = dop.analysis.trajectories.Trajectory(grid=grid, X=X + 0.01, rest=V, kind="tps")
    x = int(np.argmin(np.linalg.norm(V - [0.5, 0.1], axis=1)))
    T = {"ground truth": truth.of(x), "tps": approx.of(x)}
    picks = np.array([[-0.2, 0.0], [0.1, 0.1], [0.2, -0.2]])
    fig = dop.view.plot.plot_trajectories(shape, truth, approx, T, x, picks, jumps=np.array([[-0.1, 0.0]]))
    top = fig.axes[: 1 + len(picks)]
    # rest pose + one panel per pick, then 2 x len(T) trajectory images and 2 colour bars
    assert len(fig.axes) == 1 + len(picks) + 2 * len(T) + 2
    stars = [ln for ln in top[0].lines if ln.get_marker() == "*"]
    np.testing.assert_allclose(stars[0].get_xydata()[0], V[x])
    for ax, p in zip(top[1:], picks, strict=True):
        i, j = grid.nearest(p)
        pts = [ln.get_xydata()[0] for ln in ax.lines if ln.get_marker() == "*"]
        np.testing.assert_allclose(pts, [X[i, j, x], X[i, j, x] + 0.01])  # ground truth, then approximation
        assert f"{d[i, j, 0]:+.2f}" in ax.get_title()


def test_plot_path_trajectories_draws_each_curve_and_its_distance_to_the_reference():
    import pytest

    t = np.linspace(0, 1, 6)
    ref = np.column_stack([t, t**2, np.sin(t)])
    T = {"ground truth": ref, "linear": ref + [0.0, 0.1, 0.0], "tps": ref + 0.01 * t[:, None]}
    fig = dop.view.plot.plot_path_trajectories(t, T)
    space, err = fig.axes
    assert len(space.lines) == 3 and len(err.lines) == 2  # every trajectory in space, the approximations' errors
    assert np.allclose(err.lines[0].get_ydata(), 0.1) and np.allclose(err.lines[1].get_ydata(), 0.01 * np.sqrt(3) * t)
    with pytest.raises(ValueError, match="ground truth"):
        dop.view.plot.plot_path_trajectories(t, {"linear": ref})


def test_plot_error_over_m_marks_the_minimum_of_each_polynomial_basis():
    counts = [13, 20, 40]
    error = {"linear": np.array([3e-7, 1e-7, 9e-8]), "tps": np.array([np.nan, 5e-8, 1e-8])}
    fig = dop.view.plot.plot_error_over_m(counts, error, "(8a)/n", sizes={"linear": 13})
    (ax,) = fig.axes
    lines = [ln for ln in ax.lines if len(ln.get_xdata()) == 3]
    assert [list(ln.get_ydata()) for ln in lines][0] == list(error["linear"])
    assert any(np.allclose(ln.get_xdata(), 13) for ln in ax.lines if len(ln.get_xdata()) == 2)  # the dotted |Ψ|
    assert ax.get_xscale() == ax.get_yscale() == "log"
