"""Tests for defop.analysis.trajectories: grids, paths, plane fit, jump detection, DefOp trajectories."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from defop.analysis import trajectories as tr
from defop.geometry.mesh import Mesh
from defop.training import solves


# ----------------------------------------------------------------- fixtures
def _square_mesh(k=4):
    """A (k+1)x(k+1) grid mesh of the unit square."""
    t = np.linspace(0.0, 1.0, k + 1)
    gx, gy = np.meshgrid(t, t)
    V = np.column_stack([gx.ravel(), gy.ravel()])
    F = []
    for i in range(k):
        for j in range(k):
            a = i * (k + 1) + j
            F += [[a, a + 1, a + k + 2], [a, a + k + 2, a + k + 1]]
    return Mesh(V, np.array(F))


class _AffineDefOp:
    """Stand-in for a DefOp with the linear handle basis: X = V + W (q - p) (one moving handle)."""

    def __init__(self, mesh, p, quadratic=0.0):
        self.mesh = mesh
        self.P = np.asarray(p, dtype=float).reshape(1, 2)
        self.moving = np.array([True])
        self.meta = {"basis": "linear" if quadratic == 0 else "quadratic"}
        self.w = mesh.V[:, 0].copy()  # weight: x coordinate
        self.quadratic = quadratic

    def __call__(self, Q):
        Q = np.asarray(Q, dtype=float)
        d = Q[..., 0, :] - self.P[0]  # (k,2)
        X = self.mesh.V[None] + self.w[None, :, None] * d[:, None, :]
        X = X + self.quadratic * (d[:, None, :1] ** 2) * self.w[None, :, None]
        return X


# ------------------------------------------------------------------- grids
def test_handle_grid_layout_and_nearest():
    g = tr.handle_grid([1.0, 2.0], 0.5, 5, ny=3, radius_y=0.2)
    assert g.shape == (3, 5) and g.size == 15
    pos = g.positions
    assert pos.shape == (3, 5, 2)
    # rows follow y, columns follow x
    np.testing.assert_allclose(pos[0, :, 1], 2.0 - 0.2)
    np.testing.assert_allclose(pos[:, 0, 0], 1.0 - 0.5)
    np.testing.assert_allclose(pos[1, 2], [1.0, 2.0])  # odd sizes contain the rest position
    assert g.spacing == pytest.approx((0.25, 0.2))
    assert g.nearest([0.26, -0.15]) == (0, 3)
    assert g.extent == pytest.approx((-0.5, 0.5, -0.2, 0.2))


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"center": [0, 0], "radius": 0.0, "n": 3}, "radius"),
        ({"center": [0, 0], "radius": 1.0, "n": 1}, "n must"),
        ({"center": [0, np.nan], "radius": 1.0, "n": 3}, "center"),
    ],
)
def test_handle_grid_rejects_bad_input(kw, msg):
    with pytest.raises(ValueError, match=msg):
        tr.handle_grid(**kw)


def test_serpentine_path_visits_all_points_by_neighbour_steps():
    path = tr.serpentine_path(3, 4)
    assert path.shape == (12, 2)
    assert len({tuple(p) for p in path}) == 12
    assert (np.abs(np.diff(path, axis=0)).sum(axis=1) == 1).all()
    assert tuple(path[0]) == (0, 0) and tuple(path[4]) == (1, 3)
    top = tr.serpentine_path(3, 4, start="top")
    assert tuple(top[0]) == (2, 0)


def test_path_jumps_rejects_non_neighbour_path():
    D = np.zeros((2, 2, 2))
    with pytest.raises(ValueError, match="4-neighbours"):
        tr.path_jumps(D, np.array([[0, 0], [1, 1], [0, 1], [1, 0]]))


# ------------------------------------------------------------ plane fit, jumps
def test_plane_fit_residual_zero_for_affine_positive_for_curved():
    g = tr.handle_grid([0, 0], 1.0, 7)
    d = g.displacements
    affine = np.stack([1 + 2 * d[..., 0] - d[..., 1], 0.5 * d[..., 1]], axis=-1)
    assert tr.plane_fit_residual(g, affine) < 1e-13
    curved = affine + 0.1 * d[..., :1] ** 2
    assert tr.plane_fit_residual(g, curved) > 1e-3
    with pytest.raises(ValueError, match="does not match"):
        tr.plane_fit_residual(g, affine[:3])


def test_jump_detection_finds_a_step_and_ignores_a_ramp():
    g = tr.handle_grid([0, 0], 1.0, 21)
    d = g.displacements
    ramp = np.stack([d[..., 0], d[..., 1]], axis=-1)
    step = ramp + np.stack([np.where(d[..., 1] > 0.01, 1.0, 0.0), 0 * d[..., 0]], axis=-1)
    assert tr.jump_ratio(ramp) == pytest.approx(1.0)
    assert tr.jump_ratio(step) > 10
    assert tr.max_jump(g, ramp) == pytest.approx(1.0)
    assert tr.max_jump(g, step) > 10
    ex, ey = tr.discontinuities(step)
    assert not ex.any()
    # exactly one row of vertical edges crosses the step (y between 0 and 0.1)
    rows = np.flatnonzero(ey.any(axis=1))
    assert len(rows) == 1 and ey[rows[0]].all()
    pts = tr.discontinuity_points(g, step)
    assert pts.shape == (21, 2) and np.allclose(pts[:, 1], 0.05)


def test_path_jumps_along_serpentine():
    D = np.arange(12, dtype=float).reshape(3, 4)
    path = tr.serpentine_path(3, 4)
    j = tr.path_jumps(D, path)
    assert j.shape == (11,)
    # row ends: step from (0,3) to (1,3) jumps by 4 (one row)
    assert j[3] == pytest.approx(4.0)


# ---------------------------------------------------------- DefOp trajectories
def test_defop_trajectories_of_linear_operator_is_a_plane():
    mesh = _square_mesh(3)
    p = mesh.V[15]
    op = _AffineDefOp(mesh, p)
    g = tr.handle_grid(p, 0.3, 5)
    t = tr.defop_trajectories(op, g, batch=7)  # batch smaller than the grid: exercises chunking
    assert t.X.shape == (5, 5, mesh.n_vertices, 2)
    assert t.kind == "linear"
    v = 5
    T = t.of(v)
    np.testing.assert_allclose(T, mesh.V[v, 0] * g.displacements, atol=1e-14)
    assert tr.plane_fit_residual(g, T) < 1e-12
    np.testing.assert_allclose(t.deformation([0.0, 0.0]), mesh.V)
    quad = tr.defop_trajectories(_AffineDefOp(mesh, p, quadratic=1.0), g)
    assert tr.plane_fit_residual(g, quad.of(v)) > 1e-3
    with pytest.raises(ValueError, match="out of range"):
        t.of(mesh.n_vertices)
    with pytest.raises(ValueError, match="moving handle index"):
        tr.defop_trajectories(op, g, moving=1)


# ------------------------------------------------ ground truth with a stand-in solver
class _StubShape:
    """Minimal Shape: handle 0 (vertex 0) is fixed, handle 1 (vertex `hv`) moves."""

    def __init__(self, mesh, hv):
        self.mesh = mesh
        self.handles = np.array([0, hv])
        self.moving = np.array([False, True])

    n_moving = 1

    @property
    def P_moving(self):
        return self.mesh.V[self.handles[self.moving]]

    def targets(self, Q):
        T = self.mesh.V[self.handles].copy()
        T[self.moving] = Q
        return T


class _BistableSolver:
    """Stand-in for Solver with two branches: X = V + d + s * bump, s = +-1.

    From the automatic start (X0=None) the branch is sign(d^y) (a "global" minimiser that jumps at
    d^y = 0); warm-started, it keeps the branch of X0 unless |d^y| > 0.3 (hysteresis).
    """

    def __init__(self, mesh):
        self.mesh = mesh
        self.bump = 1.0 * np.column_stack([np.zeros(mesh.n_vertices), mesh.V[:, 0]])
        self.calls = []

    def solve(self, targets, X0=None, **kw):
        d = targets[1] - self.mesh.V[3]
        if X0 is None:
            s = 1.0 if d[1] >= 0 else -1.0
        else:
            s_prev = np.sign((X0 - self.mesh.V - d)[:, 1] @ self.mesh.V[:, 0])
            s = s_prev if abs(d[1]) <= 0.3 else np.sign(d[1])
        self.calls.append(X0 is None)

        class R:
            pass

        r = R()
        r.X = self.mesh.V + d + s * self.bump
        r.energy, r.converged = float(s), True
        return r

    def solve_best(self, targets, starts=(), rest=True, **kw):
        assert not starts and rest  # the global ground truth: the multi-start from the rest pose
        return self.solve(targets)


@pytest.fixture
def stub(monkeypatch):
    mesh = _square_mesh(3)
    shape = _StubShape(mesh, 3)
    solver = _BistableSolver(mesh)
    monkeypatch.setattr(solves, "Solver", lambda *a, **k: solver)  # the engine builds this one
    return shape, solver


def test_global_ground_truth_jumps_where_the_branch_switches(stub):
    shape, solver = stub
    g = tr.handle_grid(shape.P_moving[0], 0.5, 11, ny=10)  # even ny: d^y = 0 is between two rows
    t = tr.ground_truth_trajectories(shape, g, mode="global", n_jobs=1, cache=False)
    assert all(solver.calls) and t.converged.all() and t.path is None
    np.testing.assert_array_equal(np.sign(t.energy), np.where(g.displacements[..., 1] >= 0, 1, -1))
    ex, ey = tr.discontinuities(t.of(15))
    assert not ex.any() and np.flatnonzero(ey.any(axis=1)).tolist() == [4]


def test_local_ground_truth_follows_its_path_with_hysteresis(stub):
    shape, solver = stub
    g = tr.handle_grid(shape.P_moving[0], 0.5, 11, ny=10)
    t = tr.ground_truth_trajectories(shape, g, mode="local", n_jobs=1, cache=False)
    assert solver.calls[0] and not any(solver.calls[1:])  # only the first solve starts from scratch
    assert t.path.shape == (110, 2)
    # the serpentine scan starts at the bottom (branch -1) and keeps it until d^y > 0.3
    rows = np.flatnonzero(tr.discontinuities(t.of(15))[1].any(axis=1))
    ys = g.ys
    assert rows.tolist() == [int(np.flatnonzero(ys > 0.3)[0]) - 1]
    glob = tr.ground_truth_trajectories(shape, g, mode="global", n_jobs=1, cache=False)
    differ = np.abs(t.X - glob.X).max(axis=(2, 3)) > 1e-9
    np.testing.assert_array_equal(differ, (g.displacements[..., 1] >= 0) & (g.displacements[..., 1] <= 0.3))


def test_ground_truth_cache_round_trip(stub, tmp_path, monkeypatch):
    shape, solver = stub
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path))
    g = tr.handle_grid(shape.P_moving[0], 0.5, 3)
    a = tr.ground_truth_trajectories(shape, g, mode="local", cache=True)
    n = len(solver.calls)
    b = tr.ground_truth_trajectories(shape, g, mode="local", cache=True)
    assert len(solver.calls) == n  # second call read the cache
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.path, b.path)


def test_ground_truth_rejects_grid_not_centred_on_the_handle(stub):
    shape, _ = stub
    with pytest.raises(ValueError, match="rest position"):
        tr.ground_truth_trajectories(shape, tr.handle_grid([5.0, 5.0], 0.5, 3), cache=False)
    with pytest.raises(ValueError, match="mode"):
        tr.ground_truth_trajectories(shape, tr.handle_grid(shape.P_moving[0], 0.5, 3), mode="both", cache=False)


# ------------------------------------------------------- range and error (Figs. 3, 5)
_field = st.integers(2, 6).flatmap(
    lambda n: st.lists(st.floats(-1, 1, allow_nan=False), min_size=n * n * 2, max_size=n * n * 2).map(
        lambda v: np.reshape(v, (n, n, 2))
    )
)


@settings(max_examples=40, deadline=None)
@given(ref=_field, c=st.tuples(st.floats(-2, 2), st.floats(-2, 2)))
def test_range_and_error_of_a_shifted_trajectory(ref, c):
    """T = T_ref + c: every value moves by c, so it leaves the range by |c| and errs by |c| everywhere."""
    c = np.asarray(c)
    inside = np.full_like(ref, 0.5) * (ref.min(axis=(0, 1)) + ref.max(axis=(0, 1)))  # constant mid-range
    s = tr.range_and_error({"ground truth": ref, "shifted": ref + c, "inside": inside})
    np.testing.assert_allclose(s["shifted"]["low"], ref.min(axis=(0, 1)) + c)
    np.testing.assert_allclose(s["shifted"]["high"], ref.max(axis=(0, 1)) + c)
    np.testing.assert_allclose(s["shifted"]["overshoot"], np.abs(c), atol=1e-12)
    assert s["shifted"]["max_error"] == pytest.approx(np.linalg.norm(c), abs=1e-12)
    assert s["ground truth"]["max_error"] == 0 and not s["ground truth"]["overshoot"].any()
    assert not s["inside"]["overshoot"].any()
    np.testing.assert_allclose(s["ground truth"]["extent"], np.abs(ref).max(axis=(0, 1)))


def test_range_and_error_mask_leaves_out_points():
    ref = np.zeros((3, 4, 2))
    T = ref.copy()
    T[1, 2] = [0.0, 5.0]  # a spike: error and overshoot 5 there
    T[0, 0] = [0.0, -1.0]
    s = tr.range_and_error({"ground truth": ref, "approx": T})
    assert s["approx"]["max_error"] == 5 and s["approx"]["argmax"] == (1, 2)
    np.testing.assert_allclose(s["approx"]["overshoot"], [0, 5])
    mask = np.ones((3, 4), bool)
    mask[1, 2] = False
    m = tr.range_and_error({"ground truth": ref, "approx": T}, mask=mask)
    assert m["approx"]["max_error"] == 1 and m["approx"]["argmax"] == (0, 0)
    np.testing.assert_allclose(m["approx"]["overshoot"], [0, 1])
    np.testing.assert_allclose(m["approx"]["high"], [0, 0])


@pytest.mark.parametrize(
    "T, kw, msg",
    [
        ({"a": np.zeros((2, 2, 2))}, {}, "reference 'ground truth' is not among"),
        ({"ground truth": np.zeros((2, 2))}, {}, r"shape \(ny, nx, 2\)"),
        ({"ground truth": np.zeros((2, 2, 2)), "b": np.zeros((3, 2, 2))}, {}, "trajectory 'b' has shape"),
        ({"ground truth": np.zeros((2, 2, 2))}, {"mask": np.zeros((2, 2), bool)}, "at least one True"),
        ({"ground truth": np.zeros((2, 2, 2))}, {"mask": np.ones((2, 3), bool)}, "mask must be a boolean"),
    ],
)
def test_range_and_error_rejects_bad_input(T, kw, msg):
    with pytest.raises(ValueError, match=msg):
        tr.range_and_error(T, **kw)
