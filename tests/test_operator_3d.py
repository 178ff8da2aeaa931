"""The operator in 3D (issue 27 §3) and the empty batch (issue 26), on every evaluation path.

The Mesh class is being generalised to tetrahedra by another helper; until that lands, these tests use
:class:`TetMesh`, a stand-in built here from V (n, 3) and T (m, 4) arrays with what DefOp, fit, compress and the
spatial bases read from a mesh (V, F, sizes, the lumped volume mass matrix, the bounding-box diagonal). The
training deformations X_k are synthetic: smooth, nonlinear in Q, and exact at the handles.
"""

from __future__ import annotations

import itertools
import warnings
from math import comb

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.operator import handle_bases as hb
from defop.operator import io as opio
from defop.operator.defop import DefOp, ExtrapolationWarning
from defop.operator.fit import fit
from defop.scene import regions
from defop.training.sampling import sample_handles


class TetMesh:
    """A stand-in tetrahedral mesh: V (n,3), F (m,4) positively oriented, lumped volume mass matrix."""

    def __init__(self, V, F):
        self.V = np.ascontiguousarray(V, float)
        F = np.asarray(F, np.int64)
        vol = self.volumes_of(self.V, F)
        F[vol < 0] = F[vol < 0][:, [1, 0, 2, 3]]
        self.F = np.ascontiguousarray(F)
        self.volumes = np.abs(vol)
        assert self.volumes.min() > 0

    @staticmethod
    def volumes_of(V, F):
        a, b, c, d = (V[F[:, i]] for i in range(4))
        return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0

    n_vertices = property(lambda self: len(self.V))
    n_faces = property(lambda self: len(self.F))
    bbox_diagonal = property(lambda self: float(np.linalg.norm(np.ptp(self.V, axis=0))))

    @property
    def mass_matrix(self):
        m = np.zeros(len(self.V))
        np.add.at(m, self.F.ravel(), np.repeat(self.volumes / 4.0, 4))
        return sp.diags(m).tocsr()


def cube_bar(nx=4, ny=2, nz=2, length=2.0):
    """A length × 0.5 × 0.5 bar of nx·ny·nz cubes, each split into 6 tetrahedra (Kuhn's split)."""
    g = np.stack(np.meshgrid(*(np.arange(k + 1) for k in (nx, ny, nz)), indexing="ij"), -1).reshape(-1, 3)
    index = {tuple(p): i for i, p in enumerate(g)}
    T = []
    for c in itertools.product(range(nx), range(ny), range(nz)):
        for perm in itertools.permutations(range(3)):
            p, tet = np.array(c), [index[c]]
            for axis in perm:
                p = p + np.eye(3, dtype=int)[axis]
                tet.append(index[tuple(p)])
            T.append(tet)
    V = g * np.array([length / nx, 0.5 / ny, 0.5 / nz])
    return TetMesh(V, np.array(T))


@pytest.fixture(scope="module")
def bar3d():
    """The tet bar, its handles (3 moving at x = L, non-collinear; 4 fixed at x = 0), samples and deformations."""
    mesh = cube_bar()
    V = mesh.V
    L = V[:, 0].max()
    moving_idx = [
        int(np.flatnonzero(np.all(np.isclose(V, p), axis=1))[0]) for p in ([L, 0, 0], [L, 0.5, 0], [L, 0.25, 0.5])
    ]
    fixed_idx = [int(i) for i in np.flatnonzero(np.isclose(V[:, 0], 0) & np.isclose(V[:, 2], 0))[:3]]
    handles = np.array(moving_idx + fixed_idx)
    moving = np.array([True] * 3 + [False] * len(fixed_idx))
    P = V[moving_idx]
    Q = sample_handles(P, [{"kind": "ball", "radius": 0.3}] * 3, 24, np.random.default_rng(1))
    return mesh, handles, moving, Q, synthetic_X(mesh, handles, moving, Q)


def synthetic_X(mesh, handles, moving, Q):
    """Smooth deformations, nonlinear in Q, exact at the handles (moving at Q, fixed at rest)."""
    V = mesh.V
    P = V[handles[moving]]
    t = (V[:, 0] / V[:, 0].max())[:, None]
    w = 1.0 / (1e-3 + np.sum((V[:, None] - P[None]) ** 2, axis=-1))  # (n, n_moving)
    w = w / w.sum(axis=1, keepdims=True)
    X = []
    for q in Q:
        D = q - P
        bend = np.sin(3 * D.sum()) * 0.05 * t**2 * np.array([0.0, 1.0, 0.5]) + 0.1 * np.sum(D**2) * t * V[:, [1, 2, 0]]
        x = V + t * (w @ D) + bend
        x[handles[moving]] = q
        x[handles[~moving]] = V[handles[~moving]]
        X.append(x)
    return np.array(X)


def every_path(op, Q):
    """D(·, Q) for Q (k, n, 3) on every evaluation path: exact, batch, fast frames, and each again compressed."""
    out = {"exact": op(Q), "batch": op.evaluate_batch(Q), "fast": np.array([op.evaluate_fast(q) for q in Q])}
    op.compress(tol=1e-6)
    try:
        out |= {"c-exact": op(Q), "c-batch": op.evaluate_batch(Q), "c-fast": np.array([op.evaluate_fast(q) for q in Q])}
    finally:
        op.decompress()
    return out


# ---------------------------------------------------------------- the guarantees in 3D
def test_prop1_tps_reproduces_every_training_deformation_in_3d(bar3d):
    mesh, handles, moving, Q, X = bar3d
    op = fit(mesh, handles, moving, Q, X, "tps")
    assert op.d == 3 and op.handle_basis.kernel == "r3" and op.W.shape == (1 + 9 + 25, 3 * mesh.n_vertices)
    diag = mesh.bbox_diagonal
    paths = every_path(op, Q)
    assert np.abs(paths["exact"] - X).max() <= 1e-10 * diag  # Prop. 1, float64
    assert np.abs(paths["batch"] - X).max() <= 1e-5 * diag  # the float32 W_F rounds
    assert np.abs(paths["fast"] - paths["batch"]).max() <= 1e-6 * diag
    assert np.abs(paths["c-exact"] - X).max() <= 1e-5 * diag  # rank kept for a 1e-6 relative tail
    op.compress(rank=op.handle_basis.size - 1, dtype=np.float64)  # every direction: Prop. 1 again in float64
    assert np.abs(op(Q) - X).max() <= 1e-9 * diag
    # a linear fit cannot reproduce the nonlinear deformations: the test above could fail
    lin = fit(mesh, handles, moving, Q, X, "linear")
    assert np.abs(lin(Q) - X).max() > 1e-3 * diag


@pytest.mark.parametrize(
    "basis, spatial", [("tps", "hat"), ("linear", "hat"), ("quadratic", "hat"), ("tps", "reduced")]
)
def test_prop2_handles_and_8b_rest_pose_exact_on_every_path_in_3d(bar3d, basis, spatial):
    mesh, handles, moving, Q, X = bar3d
    if basis == "quadratic":  # C(9 + 2, 2) = 55 functions: more samples
        Q = sample_handles(mesh.V[handles[moving]], [{"kind": "ball", "radius": 0.3}] * 3, 60, 2)
        X = synthetic_X(mesh, handles, moving, Q)
    op = fit(mesh, handles, moving, Q, X, basis, spatial, k=12)
    P = op.P
    rng = np.random.default_rng(5)
    Qt = np.concatenate([P[None], P + rng.normal(scale=0.3, size=(6, 3, 3)), P[None] + 3.0])  # rest, near, far
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)
        paths = every_path(op, Qt)
    for name, D in paths.items():
        assert np.array_equal(D[:, handles[moving]], Qt), name  # Prop. 2, to the bit
        assert np.array_equal(D[:, handles[~moving]], np.broadcast_to(mesh.V[handles[~moving]], (len(Qt), 3, 3))), name
        assert np.array_equal(D[0], mesh.V), name  # (8b), to the bit
        assert not np.array_equal(D[1], mesh.V), name


def test_reduced_basis_in_3d_spans_the_affine_functions(bar3d):
    mesh = bar3d[0]
    U = dop.operator.spatial.reduced_basis(mesh, k=10)
    assert U.U.shape == (mesh.n_vertices, 10) and np.all(U.eigenvalues[:4] == 0)
    A = np.column_stack([np.ones(mesh.n_vertices), mesh.V])
    coef = np.linalg.lstsq(U.U[:, :4], A, rcond=None)[0]
    assert np.abs(U.U[:, :4] @ coef - A).max() <= 1e-10
    m = mesh.mass_matrix.diagonal()
    assert np.abs(U.U.T @ (m[:, None] * U.U) - np.eye(10)).max() <= 1e-10


def test_save_load_round_trip_in_3d(bar3d, tmp_path, monkeypatch):
    mesh, handles, moving, Q, X = bar3d
    monkeypatch.setattr(opio.files, "Mesh", TetMesh)  # until defop.geometry.mesh.Mesh takes tetrahedra
    op = fit(mesh, handles, moving, Q, X, "tps", meta={"shape": "tet bar"})
    op.save(tmp_path / "op3.npz")
    back = DefOp.load(tmp_path / "op3.npz")
    assert back.d == 3 and back.handle_basis.kernel == "r3" and np.array_equal(back(Q), op(Q))
    op.compress(rank=5)
    op.save(tmp_path / "op3c.npz")
    back = DefOp.load(tmp_path / "op3c.npz")
    assert back.rank == 5 and np.array_equal(back.evaluate_batch(Q), op.evaluate_batch(Q))


def test_wrong_dimension_is_a_clear_error(bar3d):
    mesh, handles, moving, Q, X = bar3d
    op = fit(mesh, handles, moving, Q, X, "linear")
    for call in (op, op.evaluate_batch):
        with pytest.raises(ValueError, match=r"\(3, 3\)"):
            call(np.zeros((2, 3, 2)))  # 2D Q on a 3D operator
    with pytest.raises(ValueError, match=r"Q must have shape \(3, 3\)"):
        op.evaluate_fast(np.zeros((3, 2)))
    bar2d = dop.shapes.load("bar", n_vertices=60)
    with pytest.raises(ValueError, match="trained on a 3D mesh, not a 2D one"):
        op.check_mesh(bar2d.mesh)
    with pytest.raises(ValueError, match=r"samples must have shape \(m, 3, 3\)"):
        fit(mesh, handles, moving, Q[..., :2], X, "linear")
    with pytest.raises(ValueError, match="the handle basis is in 2D, the mesh in 3D"):
        DefOp(mesh, handles, moving, hb.LinearBasis(np.zeros((3, 2))), op.W)


# ---------------------------------------------------------------- the empty batch, 2D and 3D
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("compressed", [False, True])
def test_empty_batch_on_every_path(bar3d, dim, compressed):
    if dim == 3:
        mesh, handles, moving, Q, X = bar3d
    else:
        s = dop.shapes.load("bar", n_vertices=60)
        mesh, handles, moving = s.mesh, s.handles, s.moving
        Q = sample_handles(s.P_moving, s.regions, 8, 0)
        X = np.array([dop.variational.Solver(mesh, handles, "arap").solve(s.targets(q)).X for q in Q])
    op = fit(mesh, handles, moving, Q, X, "tps")
    if compressed:
        op.compress(rank=3)
    empty = np.zeros((0, op.n_moving, dim))
    for D in (op(empty), op.evaluate_batch(empty), op.evaluate_batch(empty, out=np.empty((0, mesh.n_vertices, dim)))):
        assert D.shape == (0, mesh.n_vertices, dim) and D.dtype == np.float64
    with pytest.raises(ValueError):
        op(np.zeros((0, op.n_moving + 1, dim)))


# ---------------------------------------------------------------- Ψ and the regions in 3D
@given(n=st.integers(1, 3), m=st.integers(5, 9), seed=st.integers(0, 2**16))
@settings(max_examples=15, deadline=None)
def test_handle_bases_in_3d_sizes_and_kernel(n, m, seed):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 3))
    C = P + rng.normal(size=(m, n, 3))
    for kind, size in (("linear", 3 * n + 1), ("quadratic", comb(3 * n + 2, 2)), ("cubic", comb(3 * n + 3, 3))):
        assert hb.make_basis(kind, P).size == size == hb.basis_size(kind, n, d=3)
    b = hb.make_basis("tps", P, C, scale=0.7)
    assert b.size == 1 + 3 * n + m == hb.basis_size("tps", n, m, d=3) and b.kernel == "r3"
    Qt = P + rng.normal(size=(4, n, 3))
    psi = b(Qt)
    z = ((Qt - P) / 0.7).reshape(4, -1)
    r = np.linalg.norm(z[:, None] - ((C - P) / 0.7).reshape(m, -1)[None], axis=-1)
    assert np.allclose(psi[:, 1 + 3 * n :], r**3, rtol=1e-12, atol=1e-12)  # φ(r) = r³, an independent formula
    assert np.array_equal(psi[:, 1 : 1 + 3 * n], z)
    assert np.allclose(
        b.delta_raw(z[0] * 0.7, float(z[0] @ z[0]) * 0.49, np.empty(b.size - 1)) * b.raw_scale,
        b.delta_z(z[:1])[0],
        rtol=1e-9,
        atol=1e-9,
    )
    assert np.array_equal(b.delta_z(np.zeros((1, 3 * n))), np.zeros((1, b.size - 1)))  # δψ(0) = 0 to the bit


def test_ball_region_in_any_dimension():
    rng = np.random.default_rng(0)
    ball = regions.as_region({"kind": "ball", "radius": 0.5})
    pts = ball.sample(rng, np.array([1.0, 2.0, 3.0]), 4000)
    r = np.linalg.norm(pts - [1, 2, 3], axis=1)
    assert pts.shape == (4000, 3) and r.max() <= 0.5
    assert abs(np.mean((r / 0.5) ** 3) - 0.5) < 0.02  # uniform in volume: (r/R)³ is uniform on [0, 1]
    assert abs(np.mean(pts, axis=0) - [1, 2, 3]).max() < 0.02
    disc = regions.as_region({"kind": "disc", "radius": 0.5})
    same = (
        ball.sample(np.random.default_rng(3), np.zeros(2), 50),
        disc.sample(np.random.default_rng(3), np.zeros(2), 50),
    )
    assert np.array_equal(*same)  # in 2D a ball is a disc: the same draws
    for spec in ({"kind": "disc", "radius": 0.5}, {"kind": "circle", "radius": 1}, {"kind": "ellipse", "axes": [1, 2]}):
        with pytest.raises(ValueError, match="use {'kind': 'ball', 'radius': r} in 3D"):
            regions.as_region(spec).sample(rng, np.zeros(3), 3)
    mix = {
        "kind": "mixture",
        "components": [{"kind": "ball", "radius": 1}, {"kind": "disc", "radius": 1}],
        "weights": [1, 0],
    }
    with pytest.raises(ValueError, match="disc region is defined in 2D"):
        regions.as_region(mix).sample(rng, np.zeros(3), 3)
    for spec in ({"kind": "gaussian", "sigma": 0.1}, {"kind": "voronoi", "radius": 0.3}):
        Q = sample_handles(np.eye(3), [spec] * 3, 20, 0)
        assert Q.shape == (20, 3, 3) and np.isfinite(Q).all()
    assert [o[0].shape for o in ball.outlines(np.zeros(3))] == [(96, 3)] * 3
