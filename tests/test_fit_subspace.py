"""Problem (8) with samples Q_k in an affine subspace of the handle space (:func:`defop.operator.fit.side_conditions`).

In 3D a user who drags one handle in a plane, or moves a patch of handles together, trains on samples that never
move in some directions; the TPS linear part along them is determined by no sample. The fit pins it to zero. Checked
against an independent reference: scipy's RBFInterpolator (cubic kernel r³, degree 1) in the subspace's own
coordinates is the same interpolant for every vertex that is not a handle. Props. 1 and 2 and (8b) hold, also for Q
off the subspace.
"""

import warnings

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

import defop as dop
from defop.operator import ExtrapolationWarning
from defop.operator.fit import fit_shape, unspanned


def planar_case(name, n_vertices, m, seed):
    """Samples: the moving handles translated by one random (dx, dy, 0); X_k: a smooth field of Q_k, handles at Q_k."""
    shape = dop.shapes.load(name, n_vertices)
    rng = np.random.default_rng(seed)
    D = np.zeros((m, 3))
    D[:, :2] = rng.uniform(-0.2, 0.2, (m, 2))
    Q = shape.P_moving[None] + D[:, None, :]
    V = shape.mesh.V
    X = np.stack([V + 0.3 * np.sin(3 * V[:, [1, 2, 0]] + d[:2].sum()) * d[None, [0, 1, 0]] for d in D])
    h, mv = shape.handles, shape.moving
    X[:, h[mv]], X[:, h[~mv]] = Q, V[h[~mv]]  # the handles where problem (6) puts them
    return shape, D, Q, X


@pytest.mark.parametrize("name,nv", [("plank_3d", 165), ("bar_3d", 300)])
def test_samples_in_a_plane_fit_like_a_tps_in_the_plane(name, nv):
    shape, D, Q, X = planar_case(name, nv, 16, seed=3)
    op = fit_shape(shape, Q, X)  # raised LinAlgError (a singular triangular solve) before the pinning
    h = shape.handles
    free = np.setdiff1d(np.arange(shape.mesh.n_vertices), h)
    diag = shape.mesh.bbox_diagonal
    assert np.abs(op(Q) - X).max() / diag < 1e-9  # Prop. 1: every training deformation
    assert np.array_equal(op(shape.P_moving), shape.mesh.V)  # (8b)
    # the reference: a cubic TPS with a linear part in the plane's coordinates, rest pose included as a sample
    pts = np.vstack([np.zeros(2), D[:, :2]])
    vals = np.concatenate([shape.mesh.V[None], X])[:, free].reshape(len(pts), -1)
    ref = RBFInterpolator(pts, vals, kernel="cubic", degree=1)
    test = np.zeros((5, 3))
    test[:, :2] = np.random.default_rng(4).uniform(-0.2, 0.2, (5, 2))
    Qt = shape.P_moving[None] + test[:, None, :]
    got = op(Qt)[:, free].reshape(5, -1)
    assert np.abs(got - ref(test[:, :2])).max() / diag < 1e-8


@pytest.mark.parametrize("name,nv", [("plank_3d", 165), ("bar_3d", 300)])
def test_prop2_and_rest_pose_off_the_plane(name, nv):
    shape, _, Q, X = planar_case(name, nv, 16, seed=5)
    op = fit_shape(shape, Q, X)
    rng = np.random.default_rng(6)
    Qt = shape.P_moving[None] + rng.uniform(-0.2, 0.2, (6, 1, 3))  # dz ≠ 0: off the samples' plane
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        Xt = op(Qt)
    h, mv = shape.handles, shape.moving
    assert np.abs(Xt[:, h[mv]] - Qt).max() < 1e-12  # Prop. 2
    assert np.abs(Xt[:, h[~mv]] - shape.mesh.V[h[~mv]]).max() < 1e-12
    assert np.isfinite(Xt).all()


def test_unspanned_directions():
    rng = np.random.default_rng(0)
    B0 = np.linalg.qr(rng.normal(size=(5, 2)))[0]
    z = 0.3 + rng.normal(size=(9, 2)) @ B0.T  # 9 points on a 2-plane in R^5
    N, B = unspanned(z)
    assert N.shape == (5, 3) and B.shape == (5, 2)
    assert np.abs(N.T @ B0).max() < 1e-10 and np.abs(B.T @ B - np.eye(2)).max() < 1e-12
    N, B = unspanned(rng.normal(size=(9, 5)))  # in general position: nothing pinned
    assert N.shape == (5, 0) and B.shape == (5, 5)


@pytest.mark.parametrize("jitter", [0.0, 1e-11, 1e-8])
def test_nearly_planar_samples_are_pinned_too(jitter):
    # between 1e-10 and 1e-6 of the spread the unpinned interpolant's linear part along the normal grew to 1e3–1e5
    shape, D, Q, X = planar_case("plank_3d", 165, 16, seed=7)
    Q = Q.copy()
    Q[:, :, 2] += jitter * np.random.default_rng(8).normal(size=(len(Q), 1))
    op = fit_shape(shape, Q, X)
    assert np.abs(op(Q) - X).max() / shape.mesh.bbox_diagonal < 1e-9 + 10 * jitter  # Prop. 1, to the jitter
    off = shape.P_moving[None] + np.array([[[0.0, 0.0, 0.1]]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        moved = np.abs(op(off) - shape.mesh.V).max()
    assert moved < 1.0  # the handle moves 0.1; nothing explodes
