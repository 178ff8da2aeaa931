"""defop.lessons.figure_data: the helpers behind Figs. 2, 7, 8 and 10."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.analysis.trajectories import check_path
from defop.lessons import figure_data as fd


@given(st.integers(1, 12), st.integers(1, 12), st.sampled_from(["bottom", "top"]))
def test_column_path_visits_every_point_once_between_neighbours(ny, nx, start):
    path = fd.column_path(ny, nx, start)
    check_path(path, (ny, nx))  # raises unless a 4-neighbour path visiting every point once
    assert tuple(path[0]) == ((0, 0) if start == "bottom" else (ny - 1, 0))
    assert (np.diff(path[:ny, 1]) == 0).all()  # the first column is swept first


def test_column_path_rejects_bad_input():
    with pytest.raises(ValueError, match="positive"):
        fd.column_path(0, 3)
    with pytest.raises(ValueError, match="start"):
        fd.column_path(3, 3, "left")


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 40), st.floats(0.05, 3.0), st.integers(0, 2**31))
def test_arc_samples_lie_on_the_bending_curve(m, angle, seed):
    pivot, tip = np.array([0.02, 0.1]), np.array([0.96, 0.1])
    Q = fd.arc_samples(pivot, tip, angle, m, np.random.default_rng(seed), jitter=0.02)
    assert Q.shape == (m, 1, 2)
    d = Q[:, 0] - pivot
    a = np.arctan2(d[:, 1], d[:, 0])
    assert (np.abs(a) <= angle + 1e-12).all()
    # stratified: exactly one sample per bin of the angle range
    counts = np.histogram(a, bins=np.linspace(-angle, angle, m + 1))[0]
    assert (counts == 1).all()
    chord = np.linalg.norm(tip - pivot) * np.sinc(a / np.pi)  # a bent bar keeps its length
    np.testing.assert_array_less(np.abs(np.linalg.norm(d, axis=1) / chord - 1), 0.02 + 1e-12)


def test_arc_point_rest_and_quarter_circle():
    pivot, tip = np.array([0.0, 0.0]), np.array([1.0, 0.0])
    np.testing.assert_allclose(fd.arc_point(pivot, tip, 0.0)[0, 0], tip)
    # a chord turned by π/4 is the chord of a quarter circle of length 1: radius 2/π, chord 2√2/π
    q = fd.arc_point(pivot, tip, np.pi / 4)[0, 0]
    np.testing.assert_allclose(np.linalg.norm(q), 2 * np.sqrt(2) / np.pi)
    np.testing.assert_allclose(np.arctan2(q[1], q[0]), np.pi / 4)
    with pytest.raises(ValueError):
        fd.arc_samples(pivot, tip, 4.0, 5, np.random.default_rng(0))


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=250)


def test_subspace_floor_zero_for_affine_maps_and_hat(bar):
    rng = np.random.default_rng(3)
    V = bar.mesh.V
    A = np.eye(2) + 0.3 * rng.standard_normal((2, 2))
    X = np.stack([V @ A.T + [0.1, -0.2], V])
    assert fd.subspace_floor(bar.mesh, X, "reduced", 20) < 1e-20  # affine maps are in span Φ
    Xr = V + 0.05 * rng.standard_normal(V.shape)
    assert fd.subspace_floor(bar.mesh, Xr[None], "hat") < 1e-25  # hat functions span everything
    assert fd.subspace_floor(bar.mesh, Xr[None], "reduced", 20) > 1e-6  # noise is not smooth


def test_fit_diagnostics_interpolating_fit_has_zero_training_error(bar):
    rng = np.random.default_rng(0)
    Q = bar.P_moving[None] + rng.uniform(-0.05, 0.05, (6, 1, 2))
    X, ok = dop.training.solve_samples(bar, Q, "sarap", n_jobs=1, progress=False)
    assert ok.all()
    op = dop.operator.fit.fit_shape(bar, Q[:4], X[:4], "tps")  # TPS reproduces its samples (Prop. 1)
    d = fd.fit_diagnostics(op, Q[:4], X[:4], Q[4:], X[4:])
    assert d["train"] < 1e-20 < d["test"]
    assert d["m"] == 4 and d["size"] == op.handle_basis.size and d["cond"] >= 1


def test_lowest_of_is_at_most_every_run(bar):
    grid = dop.analysis.trajectories.handle_grid(bar.P_moving[0], 0.25, 3)
    runs = [
        dop.analysis.trajectories.ground_truth_trajectories(
            bar, grid, "sarap", mode="local", path=fd.column_path(3, 3, s), cache=False
        )
        for s in ("bottom", "top")
    ]
    g = fd.lowest_of(bar, runs)
    assert g.converged.all() and g.kind == "global"
    for r in runs:
        assert (g.energy <= r.energy * (1 + 1e-6) + 1e-14).all()
    with pytest.raises(ValueError):
        fd.lowest_of(bar, [])


def test_column_jumps_finds_a_step():
    grid = dop.analysis.trajectories.handle_grid(np.zeros(2), 1.0, 5)
    D = np.where(grid.displacements[..., 1] > 0.1, 1.0, 0.0) + 0.01 * grid.displacements[..., 0]
    y = fd.column_jumps(grid, D)
    np.testing.assert_allclose(y, 0.25)  # between the rows y = 0 and y = 0.5
    assert np.isnan(fd.column_jumps(grid, 0.01 * grid.displacements[..., 0] + 0.02 * grid.displacements[..., 1])).all()


def test_grid_error_is_zero_for_tps_through_the_grid_and_matches_the_fig8_metric(bar):
    grid = dop.analysis.trajectories.handle_grid(bar.P_moving[0], 0.1, 3)
    truth = dop.analysis.trajectories.ground_truth_trajectories(bar, grid, "sarap", cache=False, n_jobs=1)
    Q = grid.positions.reshape(-1, 1, 2)
    X = truth.X.reshape(len(Q), -1, 2)
    tps = dop.operator.fit.fit_shape(bar, Q, X, "tps")  # TPS reproduces every training deformation (Prop. 1)
    assert fd.grid_error(tps, truth) < 1e-20
    linear = dop.operator.fit.fit_shape(bar, Q, X, "linear")
    e = fd.grid_error(linear, truth)
    assert e > 1e-12
    assert e == pytest.approx(dop.analysis.approximation_error(linear, Q, X) / 9, rel=1e-12)
    other = dop.shapes.load("bar", n_vertices=120)
    with pytest.raises(ValueError, match="vertices"):
        fd.grid_error(dop.operator.fit.fit_shape(other, Q, np.repeat(other.mesh.V[None], 9, axis=0), "linear"), truth)


def test_grid_errors_over_draws_matches_one_training_per_draw(bar):
    grid = dop.analysis.trajectories.handle_grid(bar.P_moving[0], 0.1, 3)
    truth = dop.analysis.trajectories.ground_truth_trajectories(bar, grid, "sarap", cache=False, n_jobs=1)
    disc = [{"kind": "disc", "radius": 0.12}]
    E = fd.grid_errors_over_draws(bar, truth, disc, (5, 7), (0, 1), ("linear", "quadratic"))
    assert E.shape == (2, 2, 2) and (E > 0).all()
    Q = dop.training.sampling.sample_handles(bar.P_moving, disc, 7, rng=1)
    op = dop.train(bar, "sarap", "quadratic", samples=Q, progress=False)[0]
    assert E[1, 1, 1] == pytest.approx(fd.grid_error(op, truth), rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.floats(-179.0, 179.0), st.floats(0.3, 3.0), st.integers(0, 2**31))
def test_local_rotation_recovers_a_similarity(angle, scale, seed):
    rng = np.random.default_rng(seed)
    V = rng.uniform(0, 1, (60, 2))
    t = np.radians(angle)
    R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    X = scale * V @ R.T + rng.uniform(-2, 2, 2)  # rotated, scaled and moved: the angle is the rotation's
    center = V[rng.integers(len(V))]
    assert abs(fd.local_rotation(V, X, center, 0.4) - angle) < 1e-8
    # a batch: one angle per deformation; the rest pose itself turns by 0
    both = fd.local_rotation(V, np.stack([X, V]), center, 0.4)
    assert both.shape == (2,) and abs(both[0] - angle) < 1e-8 and abs(both[1]) < 1e-12


def test_local_rotation_only_sees_points_near_the_center():
    V = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [5.0, 5.0], [5.1, 5.0]])
    X = V.copy()
    X[3:] = [[5.0, 5.0], [5.0, 5.1]]  # the far pair turns by 90 degrees, the near triple stays
    assert abs(fd.local_rotation(V, X, (0, 0), 0.5)) < 1e-12
    assert abs(fd.local_rotation(V, X, (5, 5), 0.5) - 90) < 1e-9
    with pytest.raises(ValueError, match="within"):
        fd.local_rotation(V, X, (2, 2), 0.5)
    with pytest.raises(ValueError, match="shape"):
        fd.local_rotation(V, X[:3], (0, 0), 0.5)


def test_subset_fits_uses_the_first_m_samples_and_skips_undetermined_bases(bar):
    rng = np.random.default_rng(1)
    M = 12
    Q = bar.P_moving[None] + rng.uniform(-0.1, 0.1, (M, 1, 2))
    d = (Q - bar.P_moving)[:, 0]  # a smooth synthetic operator: X depends on Q through sin and cos
    X = bar.mesh.V[None] + 0.3 * np.sin(3 * d)[:, None, :] * np.cos(bar.mesh.V)[None]
    X[:, bar.handles] = [bar.targets(q) for q in Q]  # the handles where Q puts them, as (8c) asks
    bases, counts = ["linear", "quadratic", "cubic", "tps"], [2, 4, 9, 12]
    fits = fd.subset_fits(bar, Q, X, bases, counts)
    assert list(fits) == [(b, m) for b in bases for m in counts]
    for (b, m), op in fits.items():
        need = dop.training.min_samples(b, bar.n_moving)
        assert (op is None) == (m < need)
        if op is not None:
            ref = dop.operator.fit.fit_shape(bar, Q[:m], X[:m], b)
            assert op.n_samples == m and np.abs(op(Q[-3:]) - ref(Q[-3:])).max() < 1e-12
    errs = fd.subset_errors(fits, Q[-3:], X[-3:])
    for k, op in fits.items():
        if op is None:
            assert np.isnan(errs[k]).all() and errs[k].shape == (3,)
        else:
            assert abs(errs[k].sum() - dop.analysis.approximation_error(op, Q[-3:], X[-3:])) < 1e-15
    assert errs["tps", 12].max() < 1e-20  # TPS reproduces its own samples (Prop. 1)
    with pytest.raises(ValueError, match="from 1 to 12"):
        fd.subset_fits(bar, Q, X, ["tps"], [13])
    with pytest.raises(ValueError, match="basis"):
        fd.subset_fits(bar, Q, X, ["quartic"], [4])


def test_fig9_grid_marks_missing_operators_and_prints_notes(bar):
    rng = np.random.default_rng(2)
    Q = bar.P_moving[None] + rng.uniform(-0.1, 0.1, (5, 1, 2))
    X = np.stack([bar.mesh.V + 0.1 * (q - bar.P_moving)[0] for q in Q])
    X[:, bar.handles] = [bar.targets(q) for q in Q]
    fits = fd.subset_fits(bar, Q[:3], X[:3], ["cubic", "tps"], [3])  # cubic needs 9 samples: None
    rows = {f"{b}, m = {m}": op for (b, m), op in fits.items()}
    notes = {"tps, m = 3": ["a", "b"], "cubic, m = 3": ["m < |Ψ|", "m < |Ψ|"]}
    fig = dop.view.plot.plot_bases_grid(bar, Q[3:], X[3:], rows, ["one", "two"], notes=notes)
    texts = [[t.get_text() for t in ax.texts] for ax in fig.axes]
    assert len(fig.axes) == 4
    # a missing operator: an empty panel saying so, with its note (no outline, nothing over the shapes)
    assert "not fitted\nm < |Ψ|" in texts[0] and "cubic, m = 3" in texts[0] and not fig.axes[0].lines
    assert "not fitted" not in texts[2] and "a" in texts[2] and "b" in texts[3]
    assert [fig.axes[c].get_title() for c in range(2)] == ["one", "two"]
