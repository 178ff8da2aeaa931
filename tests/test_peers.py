"""The peers of notebook 12 (defop.rivals.peers) and the harness that scores them (defop.analysis.compare)."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.analysis import compare
from defop.rivals import peers
from defop.view import warp


def _perp(x):
    """x^⊥ = (−y, x), Schaefer et al.'s perpendicular."""
    return np.array([-x[1], x[0]])


def mls_reference(v, P, Q, kind, alpha=1.0):
    """MLS at one point, written straight from Schaefer, McPhail & Warren 2006, §2.2 and §2.3."""
    d = np.linalg.norm(P - v, axis=1)
    if d.min() == 0:
        return Q[np.argmin(d)]
    w = 1.0 / d ** (2 * alpha)
    p_star = w @ P / w.sum()
    q_star = w @ Q / w.sum()
    p_hat, q_hat = P - p_star, Q - q_star
    right = np.vstack([v - p_star, -_perp(v - p_star)]).T
    A = [w[i] * np.vstack([p_hat[i], -_perp(p_hat[i])]) @ right for i in range(len(P))]
    f_vec = sum(q_hat[i] @ A[i] for i in range(len(P)))
    if kind == "similarity":
        mu_s = sum(w[i] * p_hat[i] @ p_hat[i] for i in range(len(P)))
        return f_vec / mu_s + q_star
    return np.linalg.norm(v - p_star) * f_vec / np.linalg.norm(f_vec) + q_star


@pytest.fixture(scope="module")
def aleph():
    return dop.shapes.load("aleph", n_vertices=300)


def _random_Q(shape, rng, scale=0.1):
    return shape.P_moving + rng.normal(scale=scale, size=shape.P_moving.shape)


@pytest.mark.parametrize("kind", ["similarity", "rigid"])
@pytest.mark.parametrize("seed", range(4))
def test_mls_matches_a_direct_per_point_evaluation(kind, seed):
    rng = np.random.default_rng(seed)
    h = int(rng.integers(2, 8))
    P = rng.uniform(-1, 1, (h, 2))
    Q = P + rng.normal(scale=0.5, size=(h, 2))
    V = np.vstack([rng.uniform(-2, 2, (60, 2)), P[:1]])  # far points too, and one on a handle
    alpha = float(rng.uniform(0.5, 2.0))
    X = peers.mls_evaluate(peers.mls_precompute(V, P, kind, alpha), Q)
    ref = np.array([mls_reference(v, P, Q, kind, alpha) for v in V])
    np.testing.assert_allclose(X, ref, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("seed", range(3))
def test_tps_warp_interpolates_handles_and_reproduces_affine_maps(seed):
    rng = np.random.default_rng(seed)
    P = rng.uniform(-1, 1, (int(rng.integers(3, 10)), 2))
    V = np.vstack([rng.uniform(-2, 2, (80, 2)), P])
    G = peers.tps_precompute(V, P)
    Q = P + rng.normal(scale=0.3, size=P.shape)
    np.testing.assert_allclose(peers.linear_evaluate(G, Q)[-len(P) :], Q, atol=1e-9)
    A, t = rng.normal(size=(2, 2)), rng.normal(size=2)
    np.testing.assert_allclose(peers.linear_evaluate(G, P @ A.T + t), V @ A.T + t, atol=1e-9)


def test_similarity_mls_reproduces_similarities_and_rigid_mls_rotations():
    rng = np.random.default_rng(5)
    P, V = rng.uniform(-1, 1, (5, 2)), rng.uniform(-1, 1, (50, 2))
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s], [s, c]])
    t = np.array([0.3, -0.2])
    sim = peers.mls_precompute(V, P, "similarity")
    np.testing.assert_allclose(peers.mls_evaluate(sim, 1.7 * P @ R.T + t), 1.7 * V @ R.T + t, atol=1e-10)
    rig = peers.mls_precompute(V, P, "rigid")
    np.testing.assert_allclose(peers.mls_evaluate(rig, P @ R.T + t), V @ R.T + t, atol=1e-10)


@pytest.mark.parametrize("kind", peers.KINDS)
def test_every_peer_reproduces_the_rest_pose_and_interpolates_the_handles(aleph, kind):
    peer = peers.make_peer(aleph, kind, iterations=5)
    np.testing.assert_allclose(peer(aleph.P_moving), aleph.mesh.V, atol=1e-8)
    Q = _random_Q(aleph, np.random.default_rng(1))
    X = peer(Q)
    assert X.shape == (aleph.mesh.n_vertices, 2) and np.isfinite(X).all()
    np.testing.assert_allclose(X[aleph.moving_handles], Q, atol=1e-8)


def test_peers_keep_fixed_handles_at_rest_and_batch_like_defop():
    shape = dop.shapes.load("bar", n_vertices=200)
    assert (~shape.moving).any(), "the bar has fixed handles"
    rng = np.random.default_rng(2)
    Q = np.stack([_random_Q(shape, rng, 0.05) for _ in range(3)])
    for kind in ("mls-rigid", "tps", "bbw-lbs"):
        peer = peers.make_peer(shape, kind)
        X = peer(Q)
        assert X.shape == (3, shape.mesh.n_vertices, 2)
        rest = np.broadcast_to(shape.mesh.V[shape.fixed_handles], (3, len(shape.fixed_handles), 2))
        np.testing.assert_allclose(X[:, shape.fixed_handles], rest, atol=1e-8)
        np.testing.assert_allclose(X[1], peer(Q[1]), atol=1e-12)


def test_bbw_weights_are_a_partition_of_unity_in_0_1(aleph):
    W = peers.bbw_precompute(aleph.mesh, aleph.handles)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert W.min() > -1e-6 and W.max() < 1 + 1e-6
    np.testing.assert_allclose(W[aleph.handles], np.eye(len(aleph.handles)), atol=1e-8)


def test_biharmonic_coordinates_are_linearly_precise(aleph):
    W = peers.biharmonic_precompute(aleph.mesh, aleph.handles)
    np.testing.assert_allclose(W @ aleph.P, aleph.mesh.V, atol=1e-8)


def test_arap_iterations_warm_start_from_the_previous_frame(aleph):
    peer = peers.make_peer(aleph, "arap", iterations=1)
    Q = _random_Q(aleph, np.random.default_rng(3))
    first, second = peer(Q), peer(Q)
    assert not np.allclose(first, second), "a second frame continues the iterations"
    peer.reset()
    np.testing.assert_allclose(peer(Q), first, atol=1e-12)


def test_bad_input_gets_clear_errors(aleph):
    peer = peers.make_peer(aleph, "tps")
    with pytest.raises(ValueError, match=r"Q must have shape \(5, 2\)"):
        peer(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN"):
        peer(np.full((5, 2), np.nan))
    with pytest.raises(ValueError, match="handles 0 and 2 coincide"):
        peers.mls_precompute(np.zeros((3, 2)), [[0, 0], [1, 0], [0, 0]])
    with pytest.raises(ValueError, match="at least 3 point handles"):
        peers.biharmonic_precompute(aleph.mesh, aleph.handles[:2])
    with pytest.raises(ValueError, match="at least 3 handles"):
        peers.tps_precompute(np.zeros((3, 2)), [[0, 0], [1, 0]])
    with pytest.raises(ValueError, match="on one line"):
        peers.tps_precompute(np.zeros((3, 2)), [[0, 0], [1, 0], [2, 0]])
    with pytest.raises(ValueError, match="unknown peer"):
        peers.make_peer(aleph, "mls-affine")
    with pytest.raises(ValueError, match="vertex indices"):
        peers.bbw_precompute(aleph.mesh, [0, 10**6])


def test_harness_scores_the_ground_truth_itself_as_exact(aleph):
    rng = np.random.default_rng(4)
    Q = np.stack([_random_Q(aleph, rng, 0.05) for _ in range(3)])
    peer = peers.make_peer(aleph, "mls-similarity")
    s, X = compare.score(peer, aleph, Q, np.stack([peer(q) for q in Q]))
    assert s.error == 0 and s.worst == 0 and s.handle_error < 1e-12 and s.n_frames == 3
    other, _ = compare.score(peers.make_peer(aleph, "tps"), aleph, Q, X)
    assert other.error > 0 and other.worst > 0 and other.frame_best <= other.frame_median
    with pytest.raises(ValueError, match="X_true must have shape"):
        compare.score(peer, aleph, Q, X[:2])


def test_pareto_front():
    cost = np.array([1.0, 2.0, 3.0, 0.5, 2.5])
    err = np.array([5.0, 1.0, 0.5, 6.0, 2.0])
    assert compare.pareto_front(cost, err) == [3, 0, 1, 2]


# ---------------------------------------------------------------------------------------------- image warping
def _grid_mesh(x0, x1, y0, y1, k=6):
    x, y = np.meshgrid(np.linspace(x0, x1, k), np.linspace(y0, y1, k))
    V = np.column_stack([x.ravel(), y.ravel()])
    i = np.arange(k - 1)[:, None] * k + np.arange(k - 1)[None]
    i = i.ravel()
    F = np.vstack([np.column_stack([i, i + 1, i + k + 1]), np.column_stack([i, i + k + 1, i + k])])
    return V, F


@pytest.mark.parametrize("seed", range(3))
def test_piecewise_affine_warp_of_an_affine_map_is_exact_on_a_linear_image(seed):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:60, 0:80].astype(float)
    a, b, c = rng.normal(size=3)
    image = a * xx + b * yy + c  # bilinear sampling reproduces it exactly
    V, F = _grid_mesh(10.3, 69.7, 8.2, 51.9)
    A = np.eye(2) + rng.normal(scale=0.15, size=(2, 2))
    t = rng.normal(scale=2.0, size=2)
    X = (V - 40) @ A.T + 40 + t
    out = warp.warp_image(image, V, X, F, background=np.nan)
    inside = np.isfinite(out)
    py, px = np.nonzero(inside)
    src = np.linalg.solve(A, (np.column_stack([px, py]) - 40 - t).T).T + 40  # back through the affine map
    np.testing.assert_allclose(out[inside], a * src[:, 0] + b * src[:, 1] + c, atol=1e-9)
    # every pixel centre strictly inside the deformed square is covered, none outside it
    face, _ = warp.rasterize(X, F, image.shape)
    corners = X[[0, 5, 35, 30]]
    from matplotlib.path import Path

    want = Path(corners).contains_points(np.column_stack([xx.ravel(), yy.ravel()])).reshape(image.shape)
    assert np.array_equal(face >= 0, want) or np.count_nonzero((face >= 0) != want) <= 2  # ties on edges
    assert inside.sum() == (face >= 0).sum()


def test_warp_rejects_mismatched_meshes():
    V, F = _grid_mesh(0, 10, 0, 10)
    with pytest.raises(ValueError, match=rf"X must have shape \({len(V)}, 2\), got \({len(V) - 1}, 2\)"):
        warp.warp_image(np.zeros((12, 12)), V, V[:-1], F)
    with pytest.raises(ValueError, match=r"X has NaN or infinite entries \(first at vertex 0\)"):
        warp.rasterize(np.full_like(V, np.nan), F, (12, 12))


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(F=lambda F: F + 10**6), r"F refers to vertex \d+; there are \d+ vertices"),  # was a raw IndexError
        (dict(F=lambda F: F.astype(float)), r"F must be an \(m, 3\) integer array"),
        (dict(image=np.ones(5)), r"image must be a non-empty \(H, W\) or \(H, W, c\) array, got shape \(5,\)"),
        (dict(image=np.ones((0, 0))), r"image must be a non-empty"),  # returned an empty picture
        (dict(image=np.ones((12, 12)) * 1j), r"image must be an array of real numbers, got complex numbers"),
        (dict(shape=(-3, 4)), r"height must be an integer >= 1, got -3"),
        (dict(shape=(10**6, 10**6)), r"more than MAX_PIXELS"),  # was a MemoryError for 7.3 TiB
        (dict(shape=(5,)), r"shape must be \(height, width\)"),
    ],
)
def test_warp_names_its_bad_argument(change, message):
    V, F = _grid_mesh(0, 10, 0, 10)
    kw = dict(image=np.zeros((12, 12)), V=V, X=V, F=F)
    kw.update({k: v(kw[k]) if callable(v) else v for k, v in change.items()})
    with pytest.raises(ValueError, match=message):
        warp.warp_image(**kw)


def _maps(mesh, b, Q):
    """Each closed-form peer's X for handle vertices b moved to Q."""
    P = mesh.V[b]
    return {
        "MLS rigid": peers.mls_evaluate(peers.mls_precompute(mesh.V, P, "rigid"), Q),
        "MLS similarity": peers.mls_evaluate(peers.mls_precompute(mesh.V, P, "similarity"), Q),
        "TPS": peers.linear_evaluate(peers.tps_precompute(mesh.V, P), Q),
        "BBW + LBS": peers.lbs_evaluate(mesh.V, peers.bbw_precompute(mesh, b), P, Q),
        "biharmonic": peers.linear_evaluate(peers.biharmonic_precompute(mesh, b), Q),
    }


@pytest.mark.parametrize("seed", range(4))
def test_peers_do_not_depend_on_handle_order_or_subset(aleph, seed):
    """A random subset of at least 3 handles, in random order: the same map, and the handles are interpolated."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(3, len(aleph.handles) + 1))
    b = rng.choice(aleph.handles, size=k, replace=False)
    Q = aleph.mesh.V[b] + rng.normal(scale=0.08, size=(k, 2))
    perm = rng.permutation(k)
    X, Xp = _maps(aleph.mesh, b, Q), _maps(aleph.mesh, b[perm], Q[perm])
    for name in X:
        np.testing.assert_allclose(Xp[name], X[name], atol=1e-7, err_msg=name)
        np.testing.assert_allclose(X[name][b], Q, atol=1e-8, err_msg=name)


def test_frame_times_are_the_threads_cpu_time_so_load_does_not_inflate_them():
    """A frame that waits (as a preempted one does) costs no CPU time; one that computes does."""
    import time

    def waits(q):
        time.sleep(0.05)
        return np.zeros((3, 2))

    def computes(q):
        t0 = time.thread_time()
        while time.thread_time() - t0 < 0.02:
            pass
        return np.zeros((3, 2))

    _, waited = compare.run_frames(waits, np.zeros((2, 1, 2)))
    _, computed = compare.run_frames(computes, np.zeros((2, 1, 2)))
    assert waited.max() < 0.01 and computed.min() >= 0.02
