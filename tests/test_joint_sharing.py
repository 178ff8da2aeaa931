"""What the joint (P, Q) solves share (issue 44's budget): the samples of one placement one solver (its Hessian's
pattern and LDLᵀ, its bi-Laplacian's LU), every handle set on a mesh the mesh's dof pattern and bi-Laplacian; the
same verified minima, bit for bit, as a solver built per sample."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import defop as dop
from defop.scene.placement import placement_regions
from defop.training import solves
from defop.training.movable import by_placement, in_order, sample_joint, solve_joint
from defop.variational.problem import ReducedHessian
from defop.variational.solver import Solver


@pytest.fixture(scope="module")
def bar():
    shape = dop.shapes.load("bar")
    return shape, placement_regions(shape, radius=0.05 * shape.mesh.bbox_diagonal)


def few_placements(shape, pr, m, k, seed):
    """m joint samples over only k placements (each region vertex drawn from k), in a shuffled order."""
    rng = np.random.default_rng(seed)
    drawn, Q = sample_joint(shape, pr, m, rng)
    picks = rng.choice(pr.vertices[0], size=k, replace=False)
    idx = picks[rng.integers(0, k, size=m)][:, None]
    V, moving = shape.mesh.V, shape.moving
    shift = [V[pr.handles_at(i)][moving] - V[pr.handles_at(j)][moving] for i, j in zip(idx, drawn)]
    return idx, Q + np.array(shift)  # the Q regions travel with P


class Counting(Solver):
    built = []

    def __init__(self, mesh, handles, *args, **kw):
        Counting.built.append((mesh.n_vertices, tuple(np.asarray(handles).tolist())))
        super().__init__(mesh, handles, *args, **kw)


@pytest.fixture(scope="module")
def bar_3d():
    """bar_3d at about 300 vertices, its end-face patch movable: the 3D solve schedule (one level: too small for a
    coarse mesh)."""
    shape = dop.shapes.load("bar_3d", n_vertices=300)
    return shape, placement_regions(shape, radius=0.08 * shape.mesh.bbox_diagonal)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("policy", ["full", "multilevel"])
def test_one_solver_per_placement_and_the_same_minima(bar, bar_3d, dim, policy, monkeypatch):
    """Eight samples at three placements build three solvers per mesh (eight before), and end on the minima of a
    solver built per sample, bit for bit, every one verified, in 2D and 3D."""
    shape, pr = bar if dim == 2 else bar_3d
    idx, Q = few_placements(shape, pr, 8, 3, seed=3)
    assert len(np.unique(idx, axis=0)) == 3
    alone = [solve_joint(shape, pr, idx[i : i + 1], Q[i : i + 1], n_jobs=1, progress=False, cache=False,
                         policy=policy) for i in range(len(idx))]  # fmt: skip
    monkeypatch.setattr(solves, "Solver", Counting)
    Counting.built = []
    X, conv = solve_joint(shape, pr, idx, Q, n_jobs=1, progress=False, cache=False, policy=policy)
    fine = [h for n, h in Counting.built if n == shape.mesh.n_vertices]
    assert len(fine) == 3 and len(set(fine)) == 3
    coarse = [h for n, h in Counting.built if n != shape.mesh.n_vertices]
    assert len(coarse) == (3 if policy == "multilevel" and dim == 2 else 0)  # one per placement where there is one
    assert conv.all()
    for i, (x, c) in enumerate(alone):
        assert c[0] and np.array_equal(x[0], X[i])


def test_the_pool_is_bounded_and_not_pickled(bar, monkeypatch):
    """At most POOL_SIZE solvers (the most recently used kept), none shipped to a worker."""
    import pickle

    shape, pr = bar
    monkeypatch.setattr(solves, "POOL_SIZE", 2)
    problem = solves.Problem(shape.mesh, shape.handles, "sarap")
    hs = [pr.handles_at(np.array([v])) for v in pr.vertices[0][:3]]
    a = problem.solver_for(hs[0])
    problem.solver_for(hs[1])
    assert problem.solver_for(hs[0]) is a  # kept, now the most recent
    problem.solver_for(hs[2])  # evicts hs[1], the least recently used
    assert len(problem.pool) == 2 and problem.solver_for(hs[0]) is a
    assert pickle.loads(pickle.dumps(problem)).pool == {}


def test_by_placement_groups_in_first_occurrence_order():
    idx = np.array([[5, 1], [2, 2], [5, 1], [7, 0], [2, 2], [5, 1]])
    order = by_placement(idx)
    assert order.tolist() == [0, 2, 5, 1, 4, 3]
    arrays = {"X": idx[order] * 10, "cpu_seconds": np.array([1.5])}
    back = in_order(arrays, order)
    assert np.array_equal(back["X"], idx * 10) and back["cpu_seconds"].tolist() == [1.5]


def reference_pattern(mesh, free):
    """The pattern as ReducedHessian built it per handle set before (np.unique over the free-free entries)."""
    d = mesh.dim
    k = mesh.F.shape[1] * d
    dofs = (d * mesh.F[:, :, None] + np.arange(d)).reshape(len(mesh.F), -1)
    gmap = -np.ones(d * mesh.n_vertices, np.int64)
    gmap[free] = np.arange(len(free))
    r, c = gmap[np.repeat(dofs, k, axis=1).ravel()], gmap[np.tile(dofs, (1, k)).ravel()]
    keep = (r >= 0) & (c >= 0) & (r <= c)
    nf = len(free)
    uniq, inv = np.unique(c[keep] * nf + r[keep], return_inverse=True)
    ptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // nf, minlength=nf))]).astype(np.int32)
    diag = np.searchsorted(uniq, uniq[(uniq % nf) == (uniq // nf)])
    return {"_keep": np.flatnonzero(keep), "_inv": inv, "_rows": (uniq % nf).astype(np.int32), "_ptr": ptr,
            "diag": diag, "dofs": dofs}  # fmt: skip


@pytest.mark.parametrize("name, size", [("bar", None), ("bar_3d", 300)])
def test_every_handle_set_reads_the_meshs_pattern(name, size):
    """A handle set's Hessian pattern is the mesh's (built once, Mesh.dof_pairs) on its free dofs: the same arrays,
    dtypes included, as built from scratch, for random handle sets in 2D and 3D."""
    mesh = dop.shapes.load(name, size).mesh
    rng = np.random.default_rng(0)
    n, d = mesh.V.shape
    for _ in range(4):
        h = rng.choice(n, size=int(rng.integers(1, 20)), replace=False)
        free = (d * np.setdiff1d(np.arange(n), h)[:, None] + np.arange(d)).ravel()
        got = ReducedHessian(mesh, free)
        assert got.dofs is mesh.dof_pairs[0]  # the mesh's, not a copy per handle set
        for key, want in reference_pattern(mesh, free).items():
            have = getattr(got, key)
            assert have.dtype == want.dtype and np.array_equal(have, want), key
        assert got.nnz == len(got._rows)


def test_the_bilaplacian_is_built_once_per_mesh(bar, monkeypatch):
    """Two handle sets' biharmonic extensions factorise blocks of the same Mesh.bilaplacian, assembled once."""
    from defop.variational import problem

    shape, pr = bar
    mesh = dop.Mesh(shape.mesh.V, shape.mesh.F)  # a fresh mesh: nothing cached yet
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a, b = (Solver(mesh, pr.handles_at(np.array([v]))) for v in pr.vertices[0][:2])
    built, factorised = [], []
    real_q, real_splu = type(mesh).bilaplacian.func, problem.sla.splu
    monkeypatch.setattr(type(mesh).bilaplacian, "func", lambda m: built.append(1) or real_q(m))
    monkeypatch.setattr(problem.sla, "splu", lambda A, *k, **kw: factorised.append(A) or real_splu(A, *k, **kw))
    for s in (a, b):  # a displacement that is not zero: the extension factorises (zero takes no solve)
        assert np.allclose(s.extend(np.ones((len(s.handles), 2))), 1.0)
        assert s.problem._biharmonic is not None
    Q = mesh.bilaplacian
    assert len(built) == 1 and len(factorised) == 2
    for s, A in zip((a, b), factorised):
        free = s.problem.free_vertices
        assert abs(A - Q[free][:, free]).max() == 0
    L, M = mesh.cotmatrix, mesh.mass_matrix
    ref = (L.T @ (L.multiply(1.0 / M.diagonal()[:, None]))).tocsc()
    assert abs(Q - ref).max() <= 1e-12 * abs(ref).max()


def test_a_mesh_pickles_without_its_per_mesh_tables(bar):
    """dof_pairs, the bi-Laplacian and the k-d tree are rebuilt on demand, not sent with every joblib task."""
    import pickle

    shape, _ = bar
    mesh = dop.Mesh(shape.mesh.V, shape.mesh.F)
    _ = mesh.cotmatrix, mesh.mass_matrix  # what the bi-Laplacian is built from (pickled as before)
    bare = len(pickle.dumps(mesh))
    want = mesh.dof_pairs, mesh.bilaplacian
    mesh.nearest_vertex(mesh.V[:1])
    again = pickle.loads(pickle.dumps(mesh))
    assert len(pickle.dumps(mesh)) < bare + 1000
    assert all(k not in again.__dict__ for k in ("dof_pairs", "bilaplacian", "_kdtree"))
    for x, y in zip(again.dof_pairs, want[0]):
        assert np.array_equal(x, y)
    assert abs(again.bilaplacian - want[1]).max() == 0


def test_a_zero_displacement_of_the_wrong_shape_is_refused(bar):
    shape, pr = bar
    s = Solver(shape.mesh, pr.handles_at(np.array([pr.vertices[0][0]])))
    n = len(s.handles)
    assert not s.extend(np.zeros((n, 2))).any()
    for bad in (np.zeros((n - 1, 2)), np.zeros((n, 3))):
        with pytest.raises(ValueError):
            s.extend(bad)
