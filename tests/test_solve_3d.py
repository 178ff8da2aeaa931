"""The verified solver on tetrahedra (issue 27 §2): the same ``converged`` as in 2D, against independent references.

References: tests/reference3d.py (a finite-difference Newton on the tets, with no analytic eigensystem; libigl's 3D
ARAP). S-ARAP's two kink sets (σ₁ = σ₂, σ₂ = σ₃) are reached by a pinned boundary under a uniform scaling (every
tet on the triple point) and under anisotropic scalings.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import reference3d as r3
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.variational import Solver, newton, verify, volumetric
from defop.variational.problem import count_flips


def _mesh(V, T):
    return dop.Mesh(V, T)


def _assert_verified(mesh, res, handles, targets, energy):
    assert res.converged, res.reason
    assert np.isfinite(res.energy)
    assert np.abs(res.X[handles] - targets).max() <= 1e-12 * mesh.bbox_diagonal
    if energy == "sarap":
        assert count_flips(mesh, res.X) == 0


def _fd_reference(V, T, handles, targets, energy):
    """fd_newton's minimiser: ARAP from the rest pose; S-ARAP from that ARAP minimiser with μ stepped down."""
    X, info = r3.fd_newton(V, T, handles, targets, "arap", tol=1e-9)
    if energy == "sarap":
        for mu in (1e-3, 1e-5, 1e-7, 1e-9, 0.0):
            X, info = r3.fd_newton(V, T, handles, targets, "sarap", X0=X, tol=1e-9, mu=mu)
    return X, info


def _random_handles(seed):
    """A 3×3×3 grid of tets, 4 to 10 handles in random order (never all on one line), moved by up to 0.15."""
    rng = np.random.default_rng(seed)
    V, T = r3.grid_tets(3)
    while True:
        h = rng.choice(len(V), rng.integers(4, 11), replace=False)
        P = V[h] - V[h].mean(axis=0)
        if np.linalg.svd(P, compute_uv=False)[1] > 0.1:
            break
    targets = V[h] + rng.uniform(-0.15, 0.15, (len(h), 3))
    return V, T, h, targets


@pytest.mark.parametrize("energy", ["arap", "sarap"])
@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**16), cube=st.booleans())
def test_minimiser_is_the_finite_difference_newton_one(seed, energy, cube):
    """Handles in random order on the twisted cube or a 3×3×3 grid: verified, and the fd_newton minimiser.

    At the default tol (1e-9 · E on the decrement) a soft mode of a few handles leaves the point up to 1.4e-6 of the
    diagonal from fd_newton's (grid seed 0, ARAP: 6.7e-12 higher in energy, 1.3e-10 · E): the comparison runs at
    tol = 1e-13."""
    V, T, h, targets = r3.twisted_cube(seed) if cube else _random_handles(seed)
    mesh = _mesh(V, T)
    res = Solver(mesh, h, energy, tol=1e-13).solve(targets)
    _assert_verified(mesh, res, h, targets, energy)
    X, info = _fd_reference(V, T, h, targets, energy)
    assert info["grad_norm"] < 1e-6
    assert np.abs(res.X - X).max() <= 1e-6 * mesh.bbox_diagonal
    assert res.energy <= info["energy"] * (1 + 1e-9) + 1e-15


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_arap_is_libigls_within_its_single_precision_rotations(seed):
    """libigl's local–global 3D ARAP, 2000 iterations, lands 1e-6 to 1e-5 of the diagonal from the minimiser (its
    rotations are fitted in single precision): ours is no higher in energy and within 1e-4 of the diagonal."""
    V, T, h, targets = r3.twisted_cube(seed)
    mesh = _mesh(V, T)
    res = dop.solve(mesh, h, targets, energy="arap")
    _assert_verified(mesh, res, h, targets, "arap")
    X = r3.libigl_arap(V, T, h, targets, iterations=2000)
    assert res.energy <= r3.total_energy(V, T, X, "arap")
    assert np.abs(res.X - X).max() <= 1e-4 * mesh.bbox_diagonal


def _pinned_box(scale, noise, seed=1):
    V, T = r3.grid_tets(3)
    b = np.flatnonzero(((V == 0) | (V == 1)).any(axis=1))
    Vn = V + noise * np.random.default_rng(seed).normal(size=V.shape)
    return _mesh(V, T), b, Vn[b] @ np.diag(scale)


@pytest.mark.parametrize(
    "scale,kink_set",
    [
        ((0.7, 0.7, 0.7), "both"),  # every tet on the triple point σ₁ = σ₂ = σ₃
        ((1.4, 1.4, 1.4), "both"),
        ((1.6, 0.8, 0.8), "σ₂ = σ₃"),
        ((1.3, 1.3, 0.7), "σ₁ = σ₂"),
    ],
)
@pytest.mark.parametrize("noise", [0.0, 1e-5])
def test_sarap_on_both_kink_sets_converges_and_a_perturbed_resolve_is_not_lower(scale, kink_set, noise):
    """A pinned boundary under a scaling: the held tets sit on the named kink set(s), check 4 certifies the point,
    and a re-solve from a 1e-5 move of the interior does not end lower by more than verify_tol · E."""
    mesh, b, T = _pinned_box(scale, noise)
    solver = Solver(mesh, b, "sarap")
    res = solver.solve(T)
    _assert_verified(mesh, res, b, T, "sarap")
    on = volumetric.on_kink(volumetric.svd_frame(mesh.jacobians(res.X))[0], verify.KINK)
    held = {"both": on[:, 0] & on[:, 1], "σ₁ = σ₂": on[:, 0] & ~on[:, 1], "σ₂ = σ₃": on[:, 1] & ~on[:, 0]}[kink_set]
    assert held.mean() > 0.8  # most tets are held on the named set
    if not noise:  # X = V·diag(scale) is the minimum (constant stress): found to the held offsets (see Solver)
        assert np.abs(res.X - mesh.V @ np.diag(scale)).max() <= 1e-6 * mesh.bbox_diagonal
    D = np.random.default_rng(2).normal(size=mesh.V.shape)
    D[b] = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.variational.NotConvergedWarning)
        again = solver.solve(T, X0=res.X + 1e-5 * mesh.bbox_diagonal * D / np.abs(D).max())
    assert again.energy >= res.energy - solver.verify_tol * res.energy


def test_kink_pull_is_zero_at_a_uniform_scaling():
    """Every tet on the triple point with no force pulling it off (constant isotropic stress): no gain, no offset."""
    mesh, b, T = _pinned_box((0.7, 0.7, 0.7), 0.0)
    solver = Solver(mesh, b, "sarap")
    X = 0.7 * mesh.V
    assert solver.verify(X, solver.targets_of(T)).ok
    E, g, data, local = solver.grad_hess(X, 0.0, project=False, kink=verify.KINK)
    p = solver.newton_direction(g[solver.free], data, rel_shift=verify.INERTIA_SHIFT)
    gain, worst, D, pulled, offset = verify.kink_pull(solver, X, local, p, verify.KINK)
    assert gain == 0.0 and D is None and len(pulled) == 0 and offset <= 1e-12 * E


def test_verify_rejects_a_bumped_point():
    V, T, h, targets = r3.twisted_cube(3)
    mesh = _mesh(V, T)
    for energy in ("arap", "sarap"):
        solver = Solver(mesh, h, energy)
        res = solver.solve(targets)
        assert res.converged
        D = np.random.default_rng(1).normal(size=V.shape)
        D[solver.handles] = 0
        check = solver.verify(res.X + 1e-3 * D, solver.targets_of(targets))
        assert not check.ok and check.failed in ("decrement", "kink"), check.reason


def _compressed_bar():
    """A 6×1×1 bar, both end faces pinned, the far one pushed in by 26% along the axis: from the rest pose the
    straight (symmetric) compressed state is a saddle, as the 2D bar's."""
    V, T = r3.box_tets((12, 2, 2), (6.0, 1.0, 1.0))
    b = np.flatnonzero((V[:, 0] == 0) | (V[:, 0] == 6))
    targets = V[b].copy()
    targets[targets[:, 0] == 6, 0] = 6 * 0.74
    return _mesh(V, T), b, targets


def test_a_compressed_bar_is_a_saddle_without_escapes_and_buckles_with_them():
    mesh, b, targets = _compressed_bar()
    solver = Solver(mesh, b, "sarap")
    solver.max_escapes = 0
    with pytest.warns(dop.variational.NotConvergedWarning, match="saddle"):
        res = solver.solve(targets)
    assert not res.converged and "negative eigenvalue" in res.reason
    solver = Solver(mesh, b, "sarap")
    buckled = solver.solve(targets)
    _assert_verified(mesh, buckled, b, targets, "sarap")
    assert "escape" in buckled.start and buckled.energy < 0.9 * res.energy


def test_line_search_never_visits_an_inverted_tet(monkeypatch):
    """Every point the flip-free line search returns has no inverted tet (a wrapper around newton.line_search)."""
    seen = []
    inner = newton.line_search

    def recording(fun, X, P, E, slope, mesh=None, **kw):
        out = inner(fun, X, P, E, slope, mesh=mesh, **kw)
        if out is not None and mesh is not None:
            seen.append(count_flips(mesh, out[1]))
        return out

    monkeypatch.setattr(newton, "line_search", recording)
    V, T, h, targets = r3.twisted_cube(4)
    targets = targets.copy()
    top = targets[:, 2] > 0.5
    targets[top] = (targets[top] - 0.5) @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]).T + 0.5  # a 90° twist
    mesh = _mesh(V, T)
    res = dop.solve(mesh, h, targets, energy="sarap")
    _assert_verified(mesh, res, h, targets, "sarap")
    assert len(seen) > 3 and max(seen) == 0


def test_handles_on_one_line_are_refused_in_3d():
    V, T = r3.grid_tets(2)
    mesh = _mesh(V, T)
    line = np.flatnonzero((V[:, 1] == 0) & (V[:, 2] == 0))  # three handles on the x axis
    for h in ([0, 26], line, [0, 0, 26], [13]):
        with pytest.raises(ValueError, match="handles must not all lie on one line in 3D"):
            Solver(mesh, h, "arap")
    Solver(mesh, np.concatenate([line, [26]]), "arap")  # a fourth handle off the line: accepted
    with pytest.raises(ValueError, match="out of range for a mesh of 27 vertices"):
        Solver(mesh, [0, 5, 27])
    solver = Solver(mesh, [0, 5, 26, 5])
    with pytest.raises(ValueError):  # a repeated handle with two different targets
        solver.targets_of(np.array([V[0], V[5], V[26], V[5] + 0.1]))


@pytest.mark.parametrize("pair", [0, 1])
def test_kink_offset_is_the_energy_above_the_kink_and_the_fenchel_gap_vanishes_at_equilibrium(pair):
    """volumetric.kink_offset's cone cost φ(a) = r a + κ a²/2 is ψ(σ) − ψ(on the kink) to O(a³) (ψ from
    psi_value, independently), and fenchel_gap is 0 on the cone (pull inside it) and off it at equilibrium."""
    from defop.variational import kink

    rng = np.random.default_rng(pair)
    for _ in range(10):
        s, t, a = rng.uniform(0.6, 1.8), rng.uniform(0.5, 2.0), 1e-3 * rng.uniform(0.5, 1.0)
        if pair == 0:
            t = min(t, 0.9 * s)
            S, K = np.array([[s + a / np.sqrt(2), s - a / np.sqrt(2), t]]), np.array([[s, s, t]])
        else:
            t = max(t, 1.1 * s)
            S, K = np.array([[t, s + a / np.sqrt(2), s - a / np.sqrt(2)]]), np.array([[t, s, s]])
        on = np.array([[pair == 0, pair == 1]])
        off, phi = volumetric.kink_offset(S, on)
        exact = volumetric.psi_value("sarap", *S.T) - volumetric.psi_value("sarap", *K.T)
        assert abs(phi[0] - exact[0]) <= 10 * a**3  # measured ≤ 1.1e-10 at a ≤ 1e-3
        assert off[0, 2] == pytest.approx(a) and np.count_nonzero(off) == 1
        r, kappa = volumetric.kink_cone(S, on)
        F = np.zeros((1, 9))
        F[0, 2] = r[0] + kappa[0] * a  # the pull that holds the offset: equilibrium on the branch
        offset, excess = kink.fenchel_gap(S, on, np.ones(1), F)
        assert abs(offset[0] + excess[0]) < 1e-12
        F[0, 6 + 2 * pair] = 0.3 * r[0]  # a sideways pull: the gap opens
        assert sum(kink.fenchel_gap(S, on, np.ones(1), F))[0] > 0
    S = np.array([[0.7, 0.7, 0.7]])  # the triple point: a pull inside the nuclear-norm cone costs nothing
    on = np.array([[True, True]])
    r = volumetric.kink_cone(S, on)[0]
    F = np.zeros((1, 9))
    F[0, [1, 2, 6]] = 0.4 * r[0], -0.3 * r[0], 0.2 * r[0]
    assert volumetric.kink_force(on, F)[0] < r[0]
    offset, excess = kink.fenchel_gap(S, on, np.ones(1), F)
    assert offset[0] == 0.0 and excess[0] == 0.0
    F *= 4
    assert kink.fenchel_gap(S, on, np.ones(1), F)[1][0] > 0


def test_verify_names_tetrahedra_when_it_rejects_an_inverted_point():
    """Check 3 on a barrier energy: an inverted tet is rejected, and the reason says tetrahedron, not triangle."""
    mesh, b, T = _pinned_box((1.0, 1.0, 1.0), 0.0)
    solver = Solver(mesh, b, "sarap")
    X = mesh.V.copy()
    free = np.setdiff1d(np.arange(mesh.n_vertices), solver.handles)
    X[free[0]] += 10 * mesh.bbox_diagonal * np.array([1.0, 0.3, -0.2])  # drags one free vertex through the box
    check = solver.verify(X, solver.targets_of(T))
    assert count_flips(mesh, X) > 0
    assert not check.ok and check.failed in ("energy", "flips"), check.reason
    assert "tetrahedron" in check.reason and "triangle" not in check.reason
