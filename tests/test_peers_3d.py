"""The peers of notebook 12 on tetrahedral meshes (issue 27 §4): the same names and signatures as 2D, d read from
the data. Rest pose, exact handles, linear precision where the method has it, independent references (scipy's
weighted Kabsch for 3D MLS, scipy's RBFInterpolator for the 3D TPS warp, signed volumes from tests/reference3d.py
for inverted tets), and clear errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from reference3d import box_tets, volumes  # tests/ is on sys.path (rootdir conftest)

import defop as dop
from defop.analysis import compare
from defop.rivals import peers


def _corners(V, x):
    """The 4 corner vertices of the end face x = const of a box."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    return np.flatnonzero((V[:, 0] == x) & np.isin(V[:, 1], [lo[1], hi[1]]) & np.isin(V[:, 2], [lo[2], hi[2]]))


@pytest.fixture(scope="module")
def box():
    """A 1 × 0.4 × 0.4 box of 4×2×2 Kuhn cubes (45 vertices, 96 tets): 4 moving corners right, 4 fixed left."""
    V, T = box_tets((4, 2, 2), (1.0, 0.4, 0.4))
    handles = np.concatenate([np.random.default_rng(3).permutation(_corners(V, 1.0)), _corners(V, 0.0)])
    moving = np.arange(8) < 4
    return dop.Shape(
        name="box", mesh=dop.Mesh(V, T), handles=handles, moving=moving, regions=[{"kind": "ball", "radius": 0.1}] * 4
    )


def _random_Q(shape, rng, scale=0.05, k=None):
    size = shape.P_moving.shape if k is None else (k,) + shape.P_moving.shape
    return shape.P_moving + rng.normal(scale=scale, size=size)


def _affine(rng, scale=0.2):
    return np.eye(3) + rng.normal(scale=scale, size=(3, 3)), rng.normal(scale=0.3, size=3)


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)  # det +1


# ------------------------------------------------------------------------------------- every peer, one harness
@pytest.mark.parametrize("kind", peers.KINDS)
def test_every_3d_peer_reproduces_the_rest_pose_and_interpolates_the_handles(box, kind):
    peer = peers.make_peer(box, kind, iterations=5)
    diag = box.mesh.bbox_diagonal
    # libigl's 3D ARAP fits rotations with a single-precision 3x3 SVD: the rest pose comes back to ~3e-8
    tol = 1e-6 * diag if kind == "arap" else 1e-12 * diag
    np.testing.assert_allclose(peer(box.P_moving), box.mesh.V, atol=tol)
    Q = _random_Q(box, np.random.default_rng(1))
    X = peer(Q)
    assert X.shape == (box.mesh.n_vertices, 3) and np.isfinite(X).all()
    np.testing.assert_allclose(X[box.moving_handles], Q, atol=1e-12)
    np.testing.assert_allclose(X[box.fixed_handles], box.mesh.V[box.fixed_handles], atol=1e-12)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_tps_and_biharmonic_coordinates_reproduce_any_affine_map_in_3d(box, seed):
    """Linear precision: handles moved by x ↦ A x + t move every vertex by the same map (TPS, biharmonic)."""
    rng = np.random.default_rng(seed)
    A, t = _affine(rng)
    V, P = box.mesh.V, box.P
    for G in (peers.tps_precompute(V, P), peers.biharmonic_precompute(box.mesh, box.handles)):
        np.testing.assert_allclose(peers.linear_evaluate(G, P @ A.T + t), V @ A.T + t, atol=1e-9)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), s=st.floats(0.5, 2.0))
def test_3d_mls_reproduces_similarities_and_rigid_mls_rotations(seed, s):
    rng = np.random.default_rng(seed)
    P, V = rng.uniform(-1, 1, (int(rng.integers(3, 9)), 3)), rng.uniform(-1, 1, (40, 3))
    R, t = _rotation(rng), rng.normal(size=3)
    sim = peers.mls_precompute(V, P, "similarity", float(rng.uniform(0.5, 2)))
    np.testing.assert_allclose(peers.mls_evaluate(sim, s * P @ R.T + t), s * V @ R.T + t, atol=1e-9)
    rig = peers.mls_precompute(V, P, "rigid")
    np.testing.assert_allclose(peers.mls_evaluate(rig, P @ R.T + t), V @ R.T + t, atol=1e-9)


def _mls_reference(v, P, Q, kind, alpha):
    """3D MLS at one point: the weighted Procrustes fit by scipy's Kabsch (Rotation.align_vectors)."""
    from scipy.spatial.transform import Rotation

    d = np.linalg.norm(P - v, axis=1)
    if d.min() == 0:
        return Q[np.argmin(d)]
    w = 1.0 / d ** (2 * alpha)
    p_star, q_star = w @ P / w.sum(), w @ Q / w.sum()
    ph, qh = P - p_star, Q - q_star
    R = Rotation.align_vectors(qh, ph, weights=w)[0].as_matrix()  # argmin Σ w |q̂ − R p̂|²
    s = 1.0
    if kind == "similarity":
        s = np.sum(w * np.einsum("hc,hc->h", qh, ph @ R.T)) / np.sum(w * np.einsum("hc,hc->h", ph, ph))
    return s * R @ (v - p_star) + q_star


@settings(max_examples=8, deadline=None)
@given(
    kind=st.sampled_from(["similarity", "rigid"]),
    h=st.integers(3, 8),
    alpha=st.floats(0.5, 2.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_3d_mls_matches_a_per_point_kabsch_reference(kind, h, alpha, seed):
    """Random handles, targets and points (one on a handle) against scipy's weighted Kabsch, point by point."""
    rng = np.random.default_rng(seed)
    P = rng.uniform(-1, 1, (h, 3))
    Q = P + rng.normal(scale=0.3, size=(h, 3))
    V = np.vstack([rng.uniform(-2, 2, (50, 3)), P[:1]])
    X = peers.mls_evaluate(peers.mls_precompute(V, P, kind, alpha), Q)
    np.testing.assert_allclose(X, [_mls_reference(v, P, Q, kind, alpha) for v in V], rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("seed", range(3))
def test_3d_tps_warp_is_scipys_thin_plate_interpolant(seed):
    """U = r with affine side conditions is scipy's RBFInterpolator(kernel="linear", degree=1) (φ = −r)."""
    from scipy.interpolate import RBFInterpolator

    rng = np.random.default_rng(seed)
    P = rng.uniform(-1, 1, (int(rng.integers(5, 12)), 3))
    Q = P + rng.normal(scale=0.3, size=P.shape)
    V = rng.uniform(-1.5, 1.5, (60, 3))
    ref = RBFInterpolator(P, Q, kernel="linear", degree=1)(V)
    np.testing.assert_allclose(peers.linear_evaluate(peers.tps_precompute(V, P), Q), ref, atol=1e-9)


def test_bbw_on_tets_is_a_partition_of_unity_and_lbs_moves_by_translations(box):
    W = peers.bbw_precompute(box.mesh, box.handles)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert W.min() > -1e-6 and W.max() < 1 + 1e-6
    np.testing.assert_allclose(W[box.handles], np.eye(len(box.handles)), atol=1e-8)
    t = np.array([0.1, -0.2, 0.3])
    np.testing.assert_allclose(peers.lbs_evaluate(box.mesh.V, W, box.P, box.P + t), box.mesh.V + t, atol=1e-12)


def test_3d_arap_iterations_approach_a_rigid_motion(box):
    """Every handle moved by one rotation about the fixed end's centre: many iterations reach the rigid motion.

    (The warm start and reset are the same code in 2D and 3D: tests/test_peers.py.)"""
    R = _rotation(np.random.default_rng(4))
    c = box.mesh.V[box.fixed_handles].mean(axis=0)
    arap = peers.ARAPIterations(box.mesh, box.handles, iterations=300)
    X = arap((box.P - c) @ R.T + c)
    assert np.abs(X - ((box.mesh.V - c) @ R.T + c)).max() < 1e-3 * box.mesh.bbox_diagonal


# ---------------------------------------------------------------------------------- the harness: inverted tets
def test_score_counts_inverted_tets_like_signed_volumes(box):
    """A method that pushes one vertex through its neighbours: inverted tets per frame = #(signed volume ≤ 0)."""
    V, T = box.mesh.V, box.mesh.F
    inner = int(np.flatnonzero(~np.isin(np.arange(len(V)), box.mesh.boundary_vertices))[0])
    rng = np.random.default_rng(5)
    Q = _random_Q(box, rng, 0.02, k=3)
    tps = peers.make_peer(box, "tps")

    shift = np.zeros(3)

    def pushes(q):
        X = tps(q)
        X[inner] += shift
        shift[0] += 0.15  # further along x at every call
        return X

    s, X = compare.score(pushes, box, Q, tps(Q), name="pushes")
    want = np.array([np.count_nonzero(volumes(x, T) <= 0) for x in X])
    assert want[0] < want[-1]  # more inverted tets as the vertex goes further
    assert s.inverted_per_frame == s.flips_per_frame == pytest.approx(want.mean())
    assert s.frames_flipped == np.count_nonzero(want) and s.dim == 3
    table = compare.markdown_table([s])
    assert "inverted tets/frame" in table and "flips/frame" not in table


def test_score_all_on_a_3d_shape_scores_the_ground_truth_as_exact(box):
    rng = np.random.default_rng(6)
    Q = _random_Q(box, rng, 0.03, k=3)
    methods = peers.make_peers(box, kinds=("mls-rigid", "tps", "biharmonic"))
    truth = methods[1](Q)
    scores, frames = compare.score_all(methods, box, Q, truth)
    by = {s.name: s for s in scores}
    assert by["TPS warp (Bookstein)"].error == 0 and by["TPS warp (Bookstein)"].worst == 0
    assert by["MLS rigid"].error > 0 and by["biharmonic coordinates"].error > 0
    assert all(s.handle_error < 1e-12 and s.n_frames == 3 for s in scores)
    assert frames["MLS rigid"].shape == (3, box.mesh.n_vertices, 3)


# ------------------------------------------------------------------------------------------------ bad input
def test_a_2d_q_on_a_3d_peer_and_the_reverse_are_named(box):
    peer = peers.make_peer(box, "tps")
    with pytest.raises(ValueError, match=r"^Q must have shape \(4, 3\) .* got \(4, 2\) \(a 3D mesh needs 3D"):
        peer(box.P_moving[:, :2])
    flat = dop.shapes.load("bar", n_vertices=200)
    with pytest.raises(ValueError, match=r"^Q must have shape \(\d+, 2\) .* \(a 2D mesh needs 2D"):
        peers.make_peer(flat, "tps")(np.zeros((flat.n_moving, 3)))
    Q = box.P_moving[None]
    with pytest.raises(ValueError, match=r"^Q must be a batch of shape \(k, 4, 3\)"):
        compare.score(peer, box, Q[..., :2], peer(Q))
    with pytest.raises(ValueError, match=r"^X_true must have shape \(1, 45, 3\)"):
        compare.score(peer, box, Q, peer(Q)[..., :2])
    with pytest.raises(ValueError, match=r"^Q must have shape \(8, 3\)"):
        peers.mls_evaluate(peers.mls_precompute(box.mesh.V, box.P), box.P[:, :2])


def _line_handles(V):
    """Vertices on the box's edge y = z = 0, a line."""
    return np.flatnonzero((V[:, 1] == 0) & (V[:, 2] == 0))[:3]


def _plane_handles(V):
    """Vertices on the face z = 0, not on one line."""
    return np.flatnonzero(V[:, 2] == 0)[[0, 1, 5, 9]]


def test_handles_that_leave_a_rotation_free_or_lose_linear_precision_are_named(box):
    mesh = box.mesh
    line, plane = _line_handles(mesh.V), _plane_handles(mesh.V)
    with pytest.raises(ValueError, match=r"handles must not all lie on one line in 3D"):
        peers.ARAPIterations(mesh, line)
    peers.ARAPIterations(mesh, plane)  # coplanar handles pin every rotation: allowed
    with pytest.raises(ValueError, match=r"^MLS needs handles that are not all on one line"):
        peers.mls_precompute(mesh.V, mesh.V[line])
    with pytest.raises(ValueError, match=r"^the TPS warp needs handles that are not all on one plane"):
        peers.tps_precompute(mesh.V, mesh.V[plane])
    with pytest.raises(ValueError, match=r"^biharmonic coordinates need handles that are not all on one plane"):
        peers.biharmonic_precompute(mesh, plane)
    with pytest.raises(ValueError, match=r"^biharmonic coordinates need at least 4 point handles"):
        peers.biharmonic_precompute(mesh, plane[:3])
    with pytest.raises(ValueError, match=r"^the TPS warp needs at least 4 handles, got 3"):
        peers.tps_precompute(mesh.V, mesh.V[plane[:3]])
    with pytest.raises(ValueError, match=r"^P must be an array of shape \(n, 3\), got shape \(4, 2\)"):
        peers.tps_precompute(mesh.V, mesh.V[plane][:, :2])
