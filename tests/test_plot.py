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
