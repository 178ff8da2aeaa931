"""Projected Newton for problem (6): agreement with libigl's ARAP, flip-freedom, warm starts, bad input."""

from __future__ import annotations

import functools
import pickle
import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.geometry.mesh import element_dof_pattern
from defop.variational import NotConvergedWarning, Solver
from defop.variational.problem import count_flips


@pytest.fixture(scope="module")
def ginger():
    s = dop.shapes.load("gingerbread", n_vertices=400)
    rng = np.random.default_rng(3)
    Q = s.P_moving + rng.normal(scale=0.06 * s.mesh.bbox_diagonal, size=s.P_moving.shape)
    return s, s.targets(Q)


def test_arap_agrees_with_libigl(ginger):
    s, T = ginger
    solver = Solver(s.mesh, s.handles, "arap")
    X0 = dop.variational.start_for(solver, T)
    ours = solver.solve(T, X0=X0, tol=1e-12)
    igl_ = dop.variational.solve_libigl_arap(s.mesh, s.handles, T, X0=X0, iterations=3000)
    assert ours.converged
    assert abs(ours.energy - igl_.energy) <= 1e-6 * ours.energy
    assert np.abs(ours.X - igl_.X).max() <= 1e-5 * s.mesh.bbox_diagonal


def test_a_start_on_its_targets_needs_no_biharmonic_solve(ginger, monkeypatch):
    """A warm start whose handles already sit on their targets (a prolongated coarse minimum) extends a zero
    displacement: zeros without factorising the bi-Laplacian (22 ms a start at 30k vertices), the same solve bit for
    bit; a displacement that is not zero is extended as before."""
    from defop.variational import problem

    s, T = ginger
    X0 = Solver(s.mesh, s.handles, "sarap").solve(T).X
    before = Solver(s.mesh, s.handles, "sarap").solve(T, X0=X0)

    def refuse(*args):
        raise AssertionError("the bi-Laplacian was factorised for a zero displacement")

    solver = Solver(s.mesh, s.handles, "sarap")
    with monkeypatch.context() as m:
        m.setattr(problem, "biharmonic_factors", refuse)
        zero = solver.extend(np.zeros((len(solver.handles), 2)))
        after = solver.solve(T, X0=X0)
    assert zero.shape == s.mesh.V.shape and not zero.any()
    assert np.array_equal(after.X, before.X) and after.energy == before.energy
    D = np.ones((len(solver.handles), 2))
    assert np.allclose(solver.extend(D), 1.0)  # a translation extends to itself


@pytest.mark.parametrize("energy", ["sarap", "isometric", "isometric_max", "isometric_exp"])
def test_barrier_energies_far_move_is_flip_free(energy):
    s = dop.shapes.load("bar", n_vertices=300)
    T = s.targets(s.P_moving + [[-0.7, 0.0]])  # push the end into the bar: the biharmonic start flips triangles
    solver = Solver(s.mesh, s.handles, energy)
    naive = s.mesh.V + solver.extend(T - s.P)
    assert count_flips(s.mesh, naive) > 0
    res = solver.solve(T)
    assert res.converged and res.flips == 0 and np.isfinite(res.energy)
    assert np.array_equal(res.X[s.handles], T)  # hard constraints, exactly
    assert "continuation" in res.reason
    # monotone at the end: Newton descends E_μ, and E − μ·ΣA ≤ E_μ ≤ E bounds how much the true E may rise
    slack = solver.mu_schedule[-1] * s.mesh.areas.sum() + 1e-12 * res.energy
    assert np.all(np.diff(res.energy_history[-5:]) <= slack)


def test_arap_folds_where_sarap_does_not():
    """Fig. 6: ARAP folds over at a handle pulled across the body; S-ARAP's barrier keeps every triangle."""
    s = dop.shapes.load("gingerbread")
    # the configuration of notebook 01 (Fig. 6): ARAP folds 4-6 triangles on meshes of 1,100-1,300 vertices
    # (a single pulled hand folds only 0-1, depending on the mesh)
    move = np.array([[-0.4, 0.2], [0.4, 0.2], [-0.2, -0.3], [0.2, -0.3], [0.0, 0.3]])
    T = s.targets(s.P_moving + move)
    arap = dop.solve(s.mesh, s.handles, T, "arap")
    sarap = dop.solve(s.mesh, s.handles, T, "sarap")
    assert arap.converged and sarap.converged
    assert sarap.flips == 0 and arap.flips > 0


def test_warm_start_and_pickle(ginger):
    s, T = ginger
    solver = Solver(s.mesh, s.handles, "sarap")
    cold = solver.solve(T)
    again = solver.solve(T, X0=cold.X)
    assert again.converged and again.iterations <= 2
    assert again.energy == pytest.approx(cold.energy, rel=1e-9)
    T2 = T + 0.02 * s.mesh.bbox_diagonal
    warm = solver.solve(T2, X0=cold.X)
    other = pickle.loads(pickle.dumps(solver)).solve(T2, X0=cold.X)
    assert warm.converged and np.allclose(warm.X, other.X, atol=1e-12)


def test_iteration_limit_is_not_converged(ginger):
    s, T = ginger
    with pytest.warns(NotConvergedWarning, match="did not converge"):
        res = Solver(s.mesh, s.handles, "arap").solve(T, max_iter=1)
    assert not res.converged and "limit" in res.reason


def test_lbfgs_baseline_reaches_the_same_minimum(ginger):
    s, T = ginger
    newton = dop.solve(s.mesh, s.handles, T, "arap", tol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lbfgs = dop.variational.solve_lbfgs(s.mesh, s.handles, T, "arap", tol=1e-15)
    assert lbfgs.energy == pytest.approx(newton.energy, rel=1e-6)


def test_handle_given_twice(ginger):
    s, T = ginger
    h = np.append(s.handles, s.handles[0])
    ok = Solver(s.mesh, h, "arap").solve(np.vstack([T, T[0]]))
    assert ok.converged
    with pytest.raises(ValueError, match=f"vertex {s.handles[0]} is given two different targets"):
        Solver(s.mesh, h, "arap").solve(np.vstack([T, T[0] + 0.1]))


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda T: T[:-1], r"targets must have shape \(5, 2\)"),
        (lambda T: np.where(np.arange(5)[:, None] == 2, np.nan, T), "target 2 .* is not finite"),
        (lambda T: T + np.inf, "target 0 .* is not finite"),
    ],
)
def test_bad_targets(ginger, make, match):
    s, T = ginger
    with pytest.raises(ValueError, match=match):
        Solver(s.mesh, s.handles, "sarap").solve(make(T))


def test_bad_handles_and_start(ginger):
    s, T = ginger
    n = s.mesh.n_vertices
    with pytest.raises(ValueError, match=f"vertex index {n}, out of range for a mesh of {n} vertices"):
        Solver(s.mesh, np.append(s.handles, n), "sarap")
    flipped = s.mesh.V * [-1.0, 1.0]
    with pytest.raises(ValueError, match="flipped triangle.*barrier"):
        Solver(s.mesh, s.handles, "sarap").solve(T, X0=flipped)
    with pytest.raises(ValueError, match="unknown energy"):
        Solver(s.mesh, s.handles, "asap")


def test_smoothing_schedule_reaches_eq11_minimum(ginger):
    """S-ARAP's kink is smoothed by μ (E − μ·ΣA ≤ E_μ ≤ E); a schedule μ → 1e-9 reaches Eq. (11)'s own minimum."""
    s, T = ginger
    default = Solver(s.mesh, s.handles, "sarap").solve(T)
    tight = Solver(s.mesh, s.handles, "sarap", smoothing=(1e-5, 1e-7, 1e-9)).solve(T, tol=1e-12)
    assert default.converged and tight.converged and tight.flips == 0
    # the tight minimiser is at least as good on Eq. (11), and the default is within its μ bound of it
    assert tight.energy <= default.energy * (1 + 1e-12)
    assert default.energy - tight.energy <= 1e-5 * s.mesh.areas.sum()
    assert np.abs(tight.X - default.X).max() <= 1e-4 * s.mesh.bbox_diagonal  # measured 5e-6
    with pytest.raises(ValueError, match="smoothing"):
        Solver(s.mesh, s.handles, "sarap", smoothing=())


class _TetMesh:
    """A structured tetrahedral mesh of the unit cube with the attributes the solver reads from a Mesh, computed
    here for d = 3 independently of defop.geometry.mesh.Mesh: the reduced problem and its assembly read d from
    ``dim`` (the mesh's) and need nothing else."""

    def __init__(self, k=2):
        g = np.linspace(0.0, 1.0, k + 1)
        self.V = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        idx = np.arange((k + 1) ** 3).reshape(k + 1, k + 1, k + 1)
        cube = [(0, 1, 3, 7), (0, 3, 2, 7), (0, 2, 6, 7), (0, 6, 4, 7), (0, 4, 5, 7), (0, 5, 1, 7)]  # Kuhn
        F = []
        for i, j, m in np.ndindex(k, k, k):
            c = [idx[i + a, j + b, m + e] for a in (0, 1) for b in (0, 1) for e in (0, 1)]
            F += [[c[v] for v in tet] for tet in cube]
        self.F = np.array(F)
        E = np.swapaxes(self.V[self.F[:, 1:]] - self.V[self.F[:, :1]], 1, 2)  # (m,3,3) edge columns
        vol = np.linalg.det(E) / 6
        self.F[vol < 0] = self.F[vol < 0][:, [0, 2, 1, 3]]
        E = np.swapaxes(self.V[self.F[:, 1:]] - self.V[self.F[:, :1]], 1, 2)
        self.areas = np.linalg.det(E) / 6
        self.dof_pairs = element_dof_pattern(self.F, len(self.V))  # the sparsity pattern only, as a Mesh has it
        Einv = np.linalg.inv(E)
        self.local_gradients = np.concatenate([-Einv.sum(axis=1, keepdims=True), Einv], axis=1)  # (m,4,3)
        m, n = len(self.F), len(self.V)
        t = np.arange(m)
        rows = [9 * t + 3 * a + b for a in range(3) for b in range(3) for i in range(4)]
        cols = [3 * self.F[:, i] + a for a in range(3) for b in range(3) for i in range(4)]
        vals = [self.local_gradients[:, i, b] for a in range(3) for b in range(3) for i in range(4)]
        self.jacobian_operator = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(9 * m, 3 * n)
        )
        self.n_vertices = n
        self.dim = 3
        self.bbox_diagonal = float(np.sqrt(3.0))

    def jacobians(self, X):
        return (self.jacobian_operator @ np.asarray(X, float).ravel()).reshape(-1, 3, 3)


@functools.cache
def _bar_mesh():
    return dop.shapes.load("bar").mesh


def _dense_hessian(mesh, W, lamA):
    """Σ_t W_t diag(A_t λ_t) W_tᵀ scattered into the (d·n, d·n) dense matrix, element by element."""
    d = mesh.V.shape[1]
    K = np.zeros((d * mesh.n_vertices,) * 2)
    for t, f in enumerate(mesh.F):
        dofs = (d * f[:, None] + np.arange(d)).ravel()
        K[np.ix_(dofs, dofs)] += W[t] @ np.diag(lamA[t]) @ W[t].T
    return K


@settings(max_examples=10, deadline=None)
@given(d=st.sampled_from([2, 3]), seed=st.integers(0, 2**16), n_handles=st.integers(1, 8))
def test_reduced_hessian_assembles_the_dense_sum_in_any_dimension(d, seed, n_handles):
    mesh = _bar_mesh() if d == 2 else _TetMesh()
    rng = np.random.default_rng(seed)
    handles = rng.choice(mesh.n_vertices, n_handles, replace=False)
    problem = dop.variational.problem.ReducedProblem(mesh, handles, "arap")
    assert problem.dim == d and len(problem.free) == d * (mesh.n_vertices - n_handles)
    assert np.array_equal(problem.free.reshape(-1, d) // d, np.repeat(problem.free_vertices[:, None], d, 1))
    m, k = len(mesh.F), (d + 1) * d
    W, lamA = rng.normal(size=(m, k, d * d)), rng.normal(size=(m, d * d))
    K = problem.hessian.full(problem.hessian.assemble((W, lamA), project=False)).toarray()
    ref = _dense_hessian(mesh, W, lamA)[np.ix_(problem.free, problem.free)]
    assert np.allclose(K, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    Kp = problem.hessian.full(problem.hessian.assemble((W, lamA), project=True)).toarray()
    assert np.allclose(Kp, _dense_hessian(mesh, W, np.maximum(lamA, 0))[np.ix_(problem.free, problem.free)])
    p = rng.normal(size=len(problem.free))
    P = problem.full(p)
    assert (
        P.shape == (mesh.n_vertices, d)
        and np.all(P[problem.handles] == 0)
        and np.array_equal(P.ravel()[problem.free], p)
    )


def test_3d_reaches_the_volumetric_closed_forms():
    """The same solver on tets: targets (h, 3), the 3×3 closed forms behind the one face (energies.closed_forms)."""
    mesh = _TetMesh()
    solver = Solver(mesh, [0, 5, 26], "sarap")
    T = solver.targets_of(mesh.V[[0, 5, 26]] + 0.01)
    assert T.shape == (3, 3)
    with pytest.raises(ValueError, match=r"targets must have shape \(3, 3\)"):
        solver.targets_of(np.zeros((3, 2)))
    E, g, _, _ = solver.grad_hess(mesh.V)
    assert E == 0.0 and np.abs(g).max() < 1e-12  # the rest pose is a minimum of S-ARAP
    J = mesh.jacobians(mesh.V)
    assert dop.variational.energies.closed_forms(J) is dop.variational.volumetric
    # det(J(1 − 2t)) = (1 − 2t)³: a triple root at ½, found from below (5e-6 short), times the safety 0.9
    assert dop.variational.energies.max_flip_free_step(J, -2 * J) == pytest.approx(0.45, rel=1e-5)
    with pytest.raises(ValueError, match=r"J must be an \(m, d, d\) array .* got shape \(4, 2, 3\)"):
        dop.variational.energies.density(np.zeros((4, 2, 3)), "arap")
