"""The fused numba kernels (defop.variational.fused) against the numpy closed forms, the reference path.

E, ∇E, the Hessian's CSC values and the per-element modes (``local``) of ``ReducedProblem.grad_hess`` and the line
search's energies must agree to round-off (1e-12 relative) on random, near-flip and kink-held deformations, and the
solver must reach the same verified minima with either kernel.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import defop as dop
from defop.variational.problem import KERNELS, ReducedProblem, check_kernel
from defop.variational.solver import Solver

TOL = 1e-12


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar")


@pytest.fixture(scope="module")
def bar3():
    return dop.shapes.load("bar_3d")


def _rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    ok = np.isfinite(a)
    return float(np.abs(a[ok] - b[ok]).max() / max(np.abs(a[ok]).max(), 1e-300)) if ok.any() else 0.0


def _both(problem, X, mu, project, kink):
    """grad_hess and energies under each kernel."""
    out = {}
    for k in KERNELS:
        problem.kernel = k
        E, g, data, local = problem.grad_hess(X, mu, project, kink)
        out[k] = (E, g, data, local, problem.energies(X, mu), problem.energy_of(X, mu))
    problem.kernel = "numba"
    return out["numpy"], out["numba"]


def _agree(problem, X, mu, project, kink, tol=TOL):
    """Both kernels agree. In 3D the SVDs differ (LAPACK, one-sided Jacobi): the modes' signs may differ, so the
    eigenvalues and the Hessians assembled from the modes are compared, not the modes themselves."""
    (E0, g0, d0, l0, e0, f0), (E1, g1, d1, l1, e1, f1) = _both(problem, X, mu, project, kink)
    assert _rel([E0], [E1]) <= tol and _rel(e0, e1) <= tol and _rel([f0], [f1]) <= tol
    assert _rel(g0, g1) <= tol
    assert _rel(d0, d1) <= tol
    assert _rel(l0[1], l1[1]) <= tol
    if problem.dim == 2:
        assert _rel(l0[0], l1[0]) <= tol  # the modes verify.kink_pull reads
    H = problem.hessian
    for proj in (True, False):  # the numpy assembly of the numba modes, and the numba one of the numpy modes
        H.kernel = "numpy"
        ref = H.assemble(l0, proj)
        H.kernel = "numba"
        assert _rel(ref, H.assemble(l0, proj)) <= tol and _rel(ref, H.assemble(l1, proj)) <= tol
    return E0


def _smooth_field(V, rng, amp):
    """A random smooth displacement (a few sines) of amplitude ``amp`` (of the bounding box)."""
    size = np.ptp(V, axis=0).max()
    k = rng.normal(size=(3, V.shape[1])) * 4 / size
    ph = rng.uniform(0, 2 * np.pi, size=(3, V.shape[1]))
    return amp * size * sum(np.sin(V @ k[i][:, None] + ph[i]) for i in range(3))


@pytest.mark.parametrize("energy", ["arap", "sarap", "isometric"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_deformations_agree(bar, energy, seed):
    rng = np.random.default_rng(seed)
    handles = rng.choice(bar.mesh.n_vertices, rng.integers(1, 6), replace=False)
    problem = ReducedProblem(bar.mesh, handles, energy)
    V = bar.mesh.V
    angle = rng.uniform(-3, 3)
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    X = V @ R.T * rng.uniform(0.5, 2) + _smooth_field(V, rng, 0.05) + rng.uniform(-1, 1, 2)
    for mu, project in [(0.0, True), (0.0, False), (1e-5, True), (1e-2, False)]:
        _agree(problem, X, mu, project, 0.0)
    # noise that flips some triangles: barrier energies are +inf there, on both paths
    Y = X + 0.02 * np.ptp(V) * rng.normal(size=V.shape)
    E = _agree(problem, Y, 0.0, True, 0.0)
    assert np.isinf(E) == (energy != "arap" and problem.mesh.flipped(Y).any())


@pytest.mark.parametrize("energy", ["sarap", "isometric"])
def test_near_flip_agrees(bar, energy):
    """Triangles squashed to det J ~ 1e-6: the barrier terms are ~1e12 and still agree to round-off."""
    problem = ReducedProblem(bar.mesh, [0, 1], energy)
    X = bar.mesh.V @ np.diag([1.0, 1e-3]) + 1e-6 * np.sin(50 * bar.mesh.V)
    assert not problem.mesh.flipped(X).any()
    for mu, project in [(0.0, True), (1e-5, False)]:
        E = _agree(problem, X, mu, project, 0.0)
        assert E > 1e5


@pytest.mark.parametrize("seed", [0, 1])
def test_kink_held_modes_agree(bar, seed):
    """S-ARAP at μ = 0 on conformal maps (Σ = σ: Eq. 11's kink): the held modes and the released (−1) elements."""
    rng = np.random.default_rng(seed)
    problem = ReducedProblem(bar.mesh, [0], "sarap")
    V = bar.mesh.V
    X = 1.3 * V + 1e-7 * rng.normal(size=V.shape)  # every triangle within 1e-4 of the kink
    X[: len(X) // 3] += _smooth_field(V[: len(X) // 3], rng, 0.01)  # and a third of them off it
    J = bar.mesh.jacobians(X)
    on = dop.variational.planar.on_kink(dop.variational.planar.svd_frame(J)[0], 1e-4)
    assert 0 < on.sum() < len(on)
    hold = np.full(len(J), 1e-4)
    hold[rng.choice(len(J), len(J) // 4, replace=False)] = -1.0
    for kink in (1e-4, hold, 0.0):
        _agree(problem, X, 0.0, False, kink)
        _agree(problem, X, 0.0, True, kink)


@pytest.mark.parametrize("energy", ["arap", "sarap", "isometric"])
@pytest.mark.parametrize("seed", [0, 1])
def test_3d_random_and_near_flip_deformations_agree(bar3, energy, seed):
    rng = np.random.default_rng(seed)
    handles = rng.choice(bar3.mesh.n_vertices, 4, replace=False)
    problem = ReducedProblem(bar3.mesh, handles, energy)
    V = bar3.mesh.V
    X = V * rng.uniform(0.7, 1.4) + _smooth_field(V, rng, 0.03)
    for mu, project in [(0.0, True), (0.0, False), (1e-5, True), (1e-2, False)]:
        _agree(problem, X, mu, project, 0.0)
    Y = X + 0.01 * np.ptp(V) * rng.normal(size=V.shape)  # flips some tetrahedra
    _agree(problem, Y, 0.0, True, 0.0)
    if energy != "arap":
        Z = V @ np.diag([1.0, 1.0, 1e-3]) + 1e-7 * np.sin(30 * V)
        assert not problem.mesh.flipped(Z).any()
        assert _agree(problem, Z, 0.0, True, 0.0) > 1e4 * problem.mesh.areas.sum()  # ψ ~ 1e6 per unit volume


@pytest.mark.parametrize("seed", [0, 1])
def test_3d_kink_held_modes_agree(bar3, seed):
    """S-ARAP on near-conformal tetrahedra, held on both kink sets (σ₁ = σ₂ = σ₃) or one, per element and set."""
    rng = np.random.default_rng(seed)
    problem = ReducedProblem(bar3.mesh, [0, 1, 2], "sarap")
    V = bar3.mesh.V
    X = 1.3 * V + 1e-8 * rng.normal(size=V.shape)
    X[: len(X) // 3] += _smooth_field(V[: len(X) // 3], rng, 0.01)
    X[len(X) // 3 : len(X) // 2] = V[len(X) // 3 : len(X) // 2] @ np.diag([1.3, 1.3, 1.1])  # one set only
    S = dop.variational.volumetric.signed_svd(bar3.mesh.jacobians(X))[1]
    on = dop.variational.volumetric.on_kink(S, 1e-4)
    assert (on.all(axis=1)).any() and (on.any(axis=1) & ~on.all(axis=1)).any() and not on.all()
    hold = np.full((len(S), 2), 1e-4)
    # released elements (−1, as the active set releases them): off the kink, where ψ is differentiable (on it, at
    # μ = 0 and not held, the subgradient follows the round-off of Σ − σ, which each SVD rounds its own way)
    off = np.flatnonzero(~on.any(axis=1))
    hold[rng.choice(off, len(off) // 4, replace=False)] = -1.0
    # Tetrahedra exactly on a kink set have repeated singular values, whose singular vectors LAPACK and the Jacobi
    # SVD choose differently within their plane; the held modes' stiffness (1e8 times ψ's curvature) turns that
    # round-off into 1e-10 of the largest Hessian value (measured 3.7e-11), the modes' own conditioning
    for kink in (1e-4, hold, hold[:, 0]):
        _agree(problem, X, 0.0, False, kink, tol=1e-9)
        _agree(problem, X, 0.0, True, kink, tol=1e-9)
    # S-ARAP's force on the held modes, as check 4 reads it from ``local``: the same under both kernels
    from defop.variational import verify

    solver = Solver(bar3.mesh, bar3.handles, "sarap")
    p = np.random.default_rng(seed).normal(size=len(solver.free))
    pulls = []
    for k in KERNELS:
        solver.kernel = k
        local = solver.grad_hess(X, 0.0, project=False, kink=1e-4)[3]
        gain, _, D, pulled, offset = verify.kink_pull(solver, X, local, p, 1e-4)
        pulls.append((gain, offset, D, pulled))
    (g0, o0, D0, p0), (g1, o1, D1, p1) = pulls
    assert np.array_equal(p0, p1) and _rel([g0, o0], [g1, o1]) <= 1e-9
    assert D0 is None and D1 is None or _rel(D0, D1) <= 1e-9


@pytest.mark.parametrize("energy", ["arap", "sarap"])
def test_solver_reaches_the_same_minima(bar, energy):
    """Both kernels: the same verified minima, to the solver's tolerance (energies 1e-10, positions 1e-7 diag)."""
    Qs = dop.training.sampling.sample_shape(bar, 3, np.random.default_rng(5))
    results = {}
    for k in KERNELS:
        solver = Solver(bar.mesh, bar.handles, energy)
        solver.kernel = k
        results[k] = [solver.solve(bar.targets(Q)) for Q in Qs]
    for a, b in zip(results["numpy"], results["numba"]):
        assert a.converged and b.converged
        assert abs(a.energy - b.energy) <= 1e-10 * max(a.energy, 1e-12)
        assert np.abs(a.X - b.X).max() <= 1e-7 * bar.mesh.bbox_diagonal


def test_3d_solver_reaches_the_same_minima(bar3):
    Qs = dop.training.sampling.sample_shape(bar3, 2, np.random.default_rng(3))
    results = {}
    for k in KERNELS:
        solver = Solver(bar3.mesh, bar3.handles, "sarap")
        solver.kernel = k
        results[k] = [solver.solve(bar3.targets(Q)) for Q in Qs]
    for a, b in zip(results["numpy"], results["numba"]):
        assert a.converged and b.converged
        assert abs(a.energy - b.energy) <= 1e-9 * max(a.energy, 1e-12)
        assert np.abs(a.X - b.X).max() <= 1e-6 * bar3.mesh.bbox_diagonal


def test_kernel_choice(bar, monkeypatch):
    problem = ReducedProblem(bar.mesh, [0], "sarap")
    assert problem.kernel == "numba" and problem.hessian.kernel == "numba"
    problem.kernel = "numpy"
    assert problem.hessian.kernel == "numpy"
    with pytest.raises(ValueError, match="kernel must be one of numba, numpy, got 'cuda'"):
        problem.kernel = "cuda"
    assert problem.kernel == "numpy"  # unchanged
    monkeypatch.setenv("DEFOP_KERNEL", "numpy")
    assert check_kernel(None) == "numpy" and ReducedProblem(bar.mesh, [0], "arap").kernel == "numpy"
    monkeypatch.setenv("DEFOP_KERNEL", "fortran")
    with pytest.raises(ValueError, match="DEFOP_KERNEL must be one of numba, numpy, got 'fortran'"):
        check_kernel(None)
    # the isometric_max energy has no fused kernel: the numpy path runs whatever the setting
    problem = ReducedProblem(bar.mesh, [0], "isometric_max", kernel="numba")
    assert problem.elements._fused() is None


def test_pickled_solver_rebuilds_the_slot_map(bar):
    solver = Solver(bar.mesh, bar.handles, "sarap")
    X = bar.mesh.V * 1.1
    ref = solver.grad_hess(X, 1e-5)
    assert solver.hessian._slot is not None
    clone = pickle.loads(pickle.dumps(solver))
    assert clone.hessian._slot is None and clone.kernel == "numba"
    out = clone.grad_hess(X, 1e-5)
    assert out[0] == ref[0] and np.array_equal(out[2], ref[2])


@pytest.mark.parametrize("seed", range(4))
def test_flip_free_step_is_the_numpy_one(seed):
    """energies.max_flip_free_step runs the compiled pass in 2D: the same step as planar's numpy formulas, bit for bit,
    with linear (det dJ = 0), root-free and degenerate rows mixed in."""
    from defop.variational import energies, fused, planar

    rng = np.random.default_rng(seed)
    J = np.eye(2) + 0.3 * rng.normal(size=(500, 2, 2))
    J = J[np.linalg.det(J) > 0.05]
    dJ = rng.normal(size=J.shape) * rng.uniform(0.01, 3, size=(len(J), 1, 1))
    dJ[:50, 1] = 0.0  # det dJ = 0: linear in t
    dJ[50:60] = 0.0  # no motion: no root
    dJ[60:70] = -J[60:70]  # det(J(1 − t)): a double root at 1
    for safety in (0.9, 1.0):
        ref = planar.max_flip_free_step(J, dJ, safety)
        assert fused.flip_free_step2(J, dJ, safety) == ref == energies.max_flip_free_step(J, dJ, safety)
        assert energies.max_flip_free_step(J[50:60], dJ[50:60], safety) == 1.0


@pytest.mark.parametrize("seed", range(4))
def test_3d_flip_free_step_screen_changes_nothing(seed, monkeypatch):
    """volumetric.max_flip_free_step solves the cubic only where det(J + t dJ) may drop below det J / 2 before the
    step cap: the same step as solving every tetrahedron, for small and large moves, near-double roots included."""
    from defop.variational import volumetric, volumetric_step

    rng = np.random.default_rng(seed)
    J = np.eye(3) + 0.3 * rng.normal(size=(400, 3, 3))
    J = J[np.linalg.det(J) > 0.05]
    steps = []
    for scale in (1e-3, 0.1, 1.0, 10.0):
        dJ = scale * rng.normal(size=J.shape)
        if scale > 1e-3:
            dJ[:20] = -J[:20] * rng.uniform(0.5, 2.0)  # det(J (1 − a t)): a triple root at 1/a
        for safety in (0.9, 1.0):
            screened = volumetric.max_flip_free_step(J, dJ, safety)
            monkeypatch.setattr(volumetric_step, "STEP_SCREEN", np.inf)
            assert screened == volumetric.max_flip_free_step(J, dJ, safety)
            monkeypatch.setattr(volumetric_step, "STEP_SCREEN", 0.5)
            steps.append(screened)
    assert min(steps) < 0.5 and max(steps) == 1.0  # both regimes were exercised
