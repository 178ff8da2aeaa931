"""Tests for defop.trajectories: grids, paths, plane fit, jump detection, DefOp trajectories."""

import numpy as np
import pytest

from defop import trajectories as tr
from defop.mesh import Mesh


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
        (dict(center=[0, 0], radius=0.0, n=3), "radius"),
        (dict(center=[0, 0], radius=1.0, n=1), "n must"),
        (dict(center=[0, np.nan], radius=1.0, n=3), "center"),
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
