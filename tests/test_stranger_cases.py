"""Cases found by an independent stranger's test of issues 12, 14 and 15 (each failed before its fix)."""

from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest

import defop as dop


@pytest.fixture(scope="module")
def bar_op(tmp_path_factory):
    shape = dop.shapes.load("bar", n_vertices=200)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, _ = dop.train(shape, "arap", "tps", m=8, seed=1, progress=False, cache=False)
    return op


@pytest.mark.parametrize("offset", [0.0, 1e3, 1e8, -1e9])
def test_a_unit_square_far_from_the_origin_meshes(offset):
    """The shoelace area cancelled to 0 at an offset of 1e8 ('the outer polygon has zero area')."""
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) + offset
    assert dop.geometry.planar.polygon.polygon_area(sq) == 1.0
    shape = dop.shapes.from_polygon(sq, handles=[[offset + 0.5, offset + 0.5]], n_vertices=100)
    assert abs(shape.mesh.areas.sum() - 1.0) < 1e-6


def test_evaluate_fast_rejects_a_q_of_the_wrong_shape(bar_op):
    """A (1,2) Q was broadcast onto every moving handle: a silently wrong deformation."""
    n = bar_op.n_moving
    with pytest.raises(ValueError, match=rf"Q must have shape \({n}, 2\)"):
        bar_op.evaluate_fast(np.zeros((n + 1, 2)))
    with pytest.raises(ValueError, match="Q must have shape"):
        bar_op.evaluate_fast(bar_op.P.ravel())
    assert np.array_equal(bar_op.evaluate_fast(bar_op.P), bar_op.mesh.V)  # (8b) on the fast path


def test_an_empty_batch_is_an_empty_answer(bar_op):
    X = bar_op.evaluate_batch(np.zeros((0,) + bar_op.P.shape))
    assert X.shape == (0, bar_op.n_vertices, 2)


def test_complex_q_is_rejected_not_truncated(bar_op):
    with pytest.raises(ValueError, match="Q must be an array of real numbers, got complex"):
        bar_op(bar_op.P + 0j)
    with pytest.raises(ValueError, match="Qs must be an array of real numbers, got complex"):
        bar_op.evaluate_batch((bar_op.P + 0j)[None])


def test_a_misplaced_operator_entry_is_not_used(tmp_path, monkeypatch):
    """A linear operator copied over the TPS entry came back as the 'TPS' operator, with no warning."""
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    shape = dop.shapes.load("bar", n_vertices=200)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dop.train(shape, "arap", "tps", m=8, seed=1, progress=False)
        dop.train(shape, "arap", "linear", m=8, seed=1, progress=False)
    entries = sorted(tmp_path.glob("op-*.npz"))
    assert len(entries) == 2
    kinds = {p: dop.DefOp.load(p).handle_basis.kind for p in entries}
    tps = next(p for p, k in kinds.items() if k == "tps")
    lin = next(p for p, k in kinds.items() if k == "linear")
    shutil.copyfile(lin, tps)
    with pytest.warns(dop.training.cache.CacheWarning, match="not the requested"):
        op, record = dop.train(shape, "arap", "tps", m=8, seed=1, progress=False)
    assert op.handle_basis.kind == "tps" and record.cache != "operator"


def test_duplicate_samples_are_named_with_their_own_index():
    shape = dop.shapes.load("bar", n_vertices=200)
    samples = dop.training.sampling.sample_shape(shape, 6, np.random.default_rng(0))
    samples[2] = samples[0]
    with pytest.raises(ValueError, match=r"samples 0 and 2 are the same handle configuration"):
        dop.train(shape, "arap", "tps", samples=samples, progress=False, cache=False)


def test_isometric_exp_solve_does_not_crawl_from_a_huge_stage_start():
    """A full continuation stage started at ψ ~ 1e259 (finite, no flip): Newton on exp lowers the exponent by about
    one per step and ran out of its 300 iterations at E = 1.9e134, where the other energies converge in 2 stages."""
    shape = dop.shapes.load("bar", 40)
    handles = [24, 23, 22, 25]
    targets = np.array([[-0.024, 0.101], [0.077, 0.13], [0.907, 0.103], [0.118, 0.263]])
    r = dop.variational.Solver(shape.mesh, handles, "isometric_exp").solve(targets)
    assert r.converged, r.reason
    assert r.energy < 0.2  # the symmetric Dirichlet minimiser has exp-energy 0.117: a feasible upper bound


def test_handle_distortion_rejects_bad_vertices_and_non_finite_x():
    """An out-of-range vertex gave numpy's 'zero-size array to reduction operation'; 2.5 was truncated to 2; a
    boolean mask was read as the vertex indices 0 and 1; a NaN vertex was ignored (deformation_summary then gave
    area_change = nan next to finite flip counts)."""
    shape = dop.shapes.load("bar", 40)
    mesh, h = shape.mesh, shape.moving_handles
    X = mesh.V.copy()
    X[h] += 0.05
    for bad in ([mesh.n_vertices], [-1], [2.5], []):
        with pytest.raises(ValueError, match="handle|vertex"):
            dop.analysis.distortion.handle_distortion(mesh, X, bad)
    mask = np.zeros(mesh.n_vertices, bool)
    mask[h] = True
    by_mask, by_index = (dop.analysis.distortion.handle_distortion(mesh, X, v) for v in (mask, h))
    assert all(np.array_equal(by_mask[k], by_index[k]) for k in by_index)
    X[5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        dop.analysis.deformation_summary(mesh, X, h)


def test_grid_error_rejects_a_ground_truth_of_another_moving_handle():
    """grid_error(op, truth) with the default moving=0 on a ground truth solved for moving handle 1 returned an
    error 500x too large without a word (gingerbread, 5 moving handles); moving=1.5 raised numpy's IndexError."""
    shape = dop.shapes.load("gingerbread", 60)
    grid = dop.analysis.trajectories.handle_grid(shape.P_moving[1], 0.1, 3)
    Q = np.repeat(shape.P_moving[None], grid.size, axis=0)
    Q[:, 1] = grid.positions.reshape(-1, 2)
    # a synthetic ground truth: every vertex translated with handle 1 except the other handles, exactly on Q
    X = shape.mesh.V[None] + (Q[:, 1] - shape.P_moving[1])[:, None, :]
    X[:, shape.moving_handles] = Q
    truth = dop.analysis.trajectories.Trajectory(grid=grid, X=X.reshape(3, 3, -1, 2), rest=shape.mesh.V, kind="global")
    Qk = shape.P_moving + np.random.default_rng(0).normal(scale=0.05, size=(16, 5, 2))
    Xk = shape.mesh.V[None] + Qk.mean(axis=1, keepdims=True) - shape.P_moving.mean(axis=0)
    Xk[:, shape.moving_handles] = Qk
    op = dop.operator.fit.fit_shape(shape, Qk, Xk, "linear")
    assert dop.lessons.figure_data.grid_error(op, truth, moving=1) >= 0.0
    with pytest.raises(ValueError, match="another moving handle"):
        dop.lessons.figure_data.grid_error(op, truth)
    for bad in (1.5, 5, -1, "1", True):  # 5 and -1: numpy's IndexError or another handle's error before
        with pytest.raises(
            ValueError, match=r"moving \(the index of a moving handle\) must be an integer >= 0 and <= 4"
        ):
            dop.lessons.figure_data.grid_error(op, truth, moving=bad)


def test_local_rotation_rejects_nan_and_a_center_of_the_wrong_shape():
    """A NaN vertex near the center gave a NaN angle; a (3,) center raised numpy's broadcasting error."""
    V = np.random.default_rng(0).normal(size=(30, 2))
    X = V.copy()
    X[3] = np.nan
    near = np.linalg.norm(V - V[3], axis=1) <= 1.0
    assert near.sum() >= 2
    with pytest.raises(ValueError, match="NaN"):
        dop.lessons.figure_data.local_rotation(V, X, V[3], 1.0)
    with pytest.raises(ValueError, match="center"):
        dop.lessons.figure_data.local_rotation(V, V, [0.0, 0.0, 0.0], 10.0)
    c, s = np.cos(0.5), np.sin(0.5)
    turned = V @ np.array([[c, s], [-s, c]])  # rows rotated counter-clockwise by 0.5 rad
    assert dop.lessons.figure_data.local_rotation(V, turned, V[3], 1.0) == pytest.approx(np.degrees(0.5))


def test_range_and_error_rejects_nan_at_measured_points():
    """A NaN in one trajectory gave NaN low, high, extent and max_error, and an argmax pointing at the NaN."""
    ref = np.zeros((3, 3, 2))
    bad = np.ones((3, 3, 2))
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="'approx'.*NaN"):
        dop.analysis.trajectories.range_and_error({"ground truth": ref, "approx": bad})
    mask = np.ones((3, 3), bool)
    mask[0, 0] = False  # a NaN where nothing is measured is fine
    out = dop.analysis.trajectories.range_and_error({"ground truth": ref, "approx": bad}, mask=mask)
    assert out["approx"]["max_error"] == pytest.approx(np.sqrt(2))


def test_isometric_exp_still_converges_on_a_huge_stretch():
    """The stage rule above bounds the growth of max log(1 + ψ), not ψ: an absolute cap (e^20) failed this stretch,
    whose minimum has ψ ~ 1e10."""
    shape = dop.shapes.load("bar", 40)
    solver = dop.variational.Solver(shape.mesh, shape.handles, "isometric_exp")
    r = solver.solve(shape.targets(shape.P_moving + [8.0, 0.0]))
    assert r.converged, r.reason
    assert dop.variational.energies.density(shape.mesh.jacobians(r.X), "isometric_exp").max() > 1e9


def test_deformation_summary_of_a_collapsed_map_is_not_nan():
    """Every triangle collapsed to a point gave median_conformal = nan (0/0) and a RuntimeWarning."""
    shape = dop.shapes.load("bar", 40)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = dop.analysis.deformation_summary(shape.mesh, np.zeros_like(shape.mesh.V), shape.moving_handles)
    assert s["median_conformal"] == np.inf and s["flips"] == shape.mesh.n_faces and s["area_change"] == -1.0


@pytest.mark.parametrize("energy", ["isometric_max", "isometric_exp", "sarap"])
def test_energies_reject_jacobians_that_are_not_m_by_2_by_2(energy):
    """A (1,3,3) array gave ψ = 0 from its top-left 2×2 without a word; a single (2,2) matrix an IndexError.
    Now the face reads d from J: (m,3,3) is 3D (the 3×3 closed forms: ψ(I) = 0 for these energies), anything else
    is named."""
    for f in (dop.variational.energies.density, dop.variational.energies.gradient):
        out = f(np.eye(3)[None], energy)
        assert (out if f is dop.variational.energies.density else out[0]) == pytest.approx([0.0])
    cases = ((np.eye(2), r"\(m, d, d\)"), (np.ones((1, 4)), r"\(m, d, d\)"), (np.ones((1, 4, 4)), r"\(m, d, d\)"))
    for J, match in cases:
        en = dop.variational.energies
        for f in (en.density, en.gradient, en.hessian):
            with pytest.raises(ValueError, match=match):
                f(J, energy)
    assert dop.variational.energies.density(np.eye(2, dtype=int)[None], energy) == pytest.approx([0.0])


def test_isometric_max_brackets_the_squared_max_distortion():
    """MAX_POWER's comment said ψ itself is within a factor 1.04 of max(Σ, 1/σ)²: at Σ = 2, σ = 1 it is 0.74 of it
    (ψ subtracts its rest value 4^(2/p)); ψ + 4^(2/p) is what lies in [1, 4^(2/p)] times max(Σ, 1/σ)²."""
    rng = np.random.default_rng(0)
    J = np.eye(2) + 0.4 * rng.normal(size=(200, 2, 2))
    J = J[np.linalg.det(J) > 0]
    s = np.linalg.svd(J, compute_uv=False)
    top = np.maximum(s[:, 0], 1 / s[:, 1]) ** 2
    rest = 4 ** (2 / dop.variational.energies.MAX_POWER)
    shifted = dop.variational.energies.density(J, "isometric_max") + rest
    assert np.all(top * (1 - 1e-12) <= shifted) and np.all(shifted <= rest * top * (1 + 1e-12))


def _star_3273():
    from test_solve_verified import star_with_hole

    seed = 3273
    mesh = star_with_hole(seed).mesh
    rng = np.random.default_rng(seed + 1)
    h = rng.choice(mesh.n_vertices, 3, replace=False)
    T = mesh.V[h] + 0.06699653241756179 * mesh.bbox_diagonal * rng.normal(size=(3, 2))
    return mesh, h, T


def _perturbed_resolve(solver, T, X):
    D = np.random.default_rng(0).normal(size=X.shape)
    D[solver.handles] = 0
    D *= 1e-5 * solver.mesh.bbox_diagonal / np.abs(D).max()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.variational.NotConvergedWarning)
        return solver.solve(T, X0=X + D)


def test_sarap_converged_is_a_local_minimum_on_star_3273():
    """A random star with a hole (seed 3273), 3 handles, S-ARAP (found by hypothesis on 2026-11-23): the solver
    reported converged (decrement 1.6e-11) at a point where one triangle, held on Eq. (11)'s kink by check 4, is
    pulled off it 1.083 times harder than its cone bears; a re-solve from a 1e-5 perturbation ended 1.6e-5 lower.
    Now the μ = 0 Newton stage releases that triangle (active set) and ends at the lower minimum."""
    mesh, h, T = _star_3273()
    solver = dop.variational.Solver(mesh, h, "sarap")
    a = solver.solve(T)
    assert a.converged and a.start == "rest" and "1 triangle(s) released from the kink" in a.reason
    assert a.energy < 0.53895159 * (1 - 1.5e-5)  # the old point: 0.5389515952
    b = _perturbed_resolve(solver, T, a.X)
    assert b.energy >= a.energy * (1 - 1e-9)


def test_star_3273_without_releases_escapes_the_kink_from_check_4(monkeypatch):
    """The second line of defence: with no releases in Newton, check 4 fails ("kink") at the old point and the
    solve escapes along the pull, as it escapes a saddle, to the same minimum."""
    mesh, h, T = _star_3273()
    monkeypatch.setattr(dop.variational.newton, "MAX_RELEASES", 0)
    solver = dop.variational.Solver(mesh, h, "sarap")
    smoothed = solver.solve(T)  # the smoothing continuation (the held point's Fenchel gap is large) gets there first
    assert smoothed.converged and smoothed.start == "rest" and "smoothing continued" in smoothed.reason
    monkeypatch.setattr(dop.variational.newton, "KINK_TARGET", np.inf)  # no continuation either
    a = solver.solve(T)
    assert a.converged and a.start == "rest > off kink"
    assert [c[2] for c in a.candidates] == [False, True]
    assert a.energy < a.candidates[0][1] * (1 - 1.5e-5)
    assert smoothed.energy == pytest.approx(a.energy, rel=1e-7)


def test_the_old_check_4_passed_star_3273_and_verify_now_rejects_that_point(monkeypatch):
    """Without the equilibrium test on the cone (the old check 4), the solve stops on the kink and calls it
    converged; :meth:`Solver.verify` rejects that point with "kink" and names the triangle and its pull."""
    mesh, h, T = _star_3273()
    solver = dop.variational.Solver(mesh, h, "sarap")
    no_pull = lambda solver, X, local, p, hold: (0.0, None, None, [], 0.0)  # noqa: E731
    monkeypatch.setattr(dop.variational.verify, "kink_pull", no_pull)  # check 4
    monkeypatch.setattr(dop.variational.kink, "kink_pull", no_pull)  # the releases of kink_active_set, kink_gap
    old = solver.solve(T)
    assert old.converged and old.start == "rest"
    monkeypatch.undo()
    check = solver.verify(old.X, solver.targets_of(T))
    assert check.failed == "kink" and "triangle 6 is pulled off it by 1.08" in check.reason
    b = _perturbed_resolve(solver, T, old.X)
    assert b.converged and b.energy < old.energy * (1 - 1.5e-5)


def test_analysis_and_trajectories_name_bad_input():
    """Found by a stranger's probe on 2026-11-24: a NaN ground truth gave an error of nan, a single Q (n,2) an
    IndexError in flips, repeats=0 or k=0 timed anyway (k=0: 0 FPS), batch=0 a range() error, a list for the grid
    an AttributeError, and pareto_front left a NaN method off the front without a word."""
    s = dop.shapes.load("bar")
    op, _ = dop.train(s, "sarap", "tps", m=17, seed=0, progress=False)
    Qs = s.P_moving + 0.05 * np.random.default_rng(0).normal(size=(3, s.n_moving, 2))
    X = op(Qs)
    with pytest.raises(ValueError, match=r"X_true has NaN or infinite entries \(first in sample 1\)"):
        dop.analysis.approximation_error(op, Qs, np.where(np.arange(3)[:, None, None] == 1, np.nan, X))
    with pytest.raises(ValueError, match=r"samples must have shape \(k, 1, 2\), k >= 1"):
        dop.analysis.flips(op, Qs[0])
    with pytest.raises(ValueError, match="repeats must be an integer >= 1, got 0"):
        dop.analysis.metrics.frame_rate(op, Qs, repeats=0)
    with pytest.raises(ValueError, match="k must be an integer >= 1, got 0"):
        dop.analysis.metrics.batch_frame_rate(op, Qs, k=0)
    grid = dop.analysis.trajectories.handle_grid(s.P_moving[0], 0.1, 3)
    with pytest.raises(ValueError, match="batch must be an integer >= 1, got 0"):
        dop.analysis.trajectories.defop_trajectories(op, grid, batch=0)
    with pytest.raises(ValueError, match="grid must be a HandleGrid"):
        dop.analysis.trajectories.defop_trajectories(op, [[0.0, 0.0]])
    with pytest.raises(ValueError, match="cost and error must be finite"):
        dop.analysis.compare.pareto_front([1.0, np.nan], [1.0, 2.0])
    with pytest.raises(ValueError, match="one length"):
        dop.analysis.compare.pareto_front([1.0, 2.0], [1.0])
    assert dop.analysis.approximation_error(op, Qs, X) == 0.0
