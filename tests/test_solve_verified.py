"""``converged`` means a verified local minimum, for any handle order (issue 12).

Property tests on random star-shaped polygons with a hole (random handle subsets in random order, duplicates
carrying equal targets, random moves), an independent finite-difference Newton reference, the buckling bar's
saddle, and one regression test per case of the issue.
"""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.variational import NotConvergedWarning, Solver


# ---------------------------------------------------------------- shapes
def star_with_hole(seed, n_vertices=100):
    """A random star-shaped polygon (8-12 corners) with a hexagonal hole, meshed by Triangle."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(8, 13))
    t = (np.arange(k) + rng.uniform(-0.2, 0.2, k)) * 2 * np.pi / k  # corners at least 0.71 from the centre
    r = rng.uniform(0.8, 1.3, k)
    outer = np.column_stack([r * np.cos(t), r * np.sin(t)])
    a = np.linspace(0, 2 * np.pi, 7)[:-1]
    hole = rng.uniform(0.15, 0.3) * np.column_stack([np.cos(a), np.sin(a)])[::-1] + rng.uniform(-0.1, 0.1, 2)
    return dop.shapes.from_polygon(outer, [hole], handles=np.array([[0.55, 0.0]]), n_vertices=n_vertices)


def _energy_from_scratch(V, F, X, energy):
    """Σ A_t ψ(J_t) with numpy's SVD (no defop code): ARAP (Eq. 10) or isometric; signed σ when det J < 0."""
    Dr = np.swapaxes(V[F[:, 1:]] - V[F[:, :1]], 1, 2)
    Dx = np.swapaxes(X[F[:, 1:]] - X[F[:, :1]], 1, 2)
    J = Dx @ np.linalg.inv(Dr)
    s = np.linalg.svd(J, compute_uv=False)
    s[:, 1] *= np.sign(np.linalg.det(J))
    A = 0.5 * np.abs(np.linalg.det(Dr))
    if energy == "arap":
        return float(A @ ((s[:, 0] - 1) ** 2 + (s[:, 1] - 1) ** 2))
    if np.any(s[:, 1] <= 0):
        return np.inf
    return float(A @ (s[:, 0] ** 2 + s[:, 1] ** 2 + s[:, 0] ** -2 + s[:, 1] ** -2))


def _fd_hessian_of_gradient(solver, X):
    """Dense Hessian of the true energy on the free dofs by central differences of the analytic gradient."""
    free = solver.free

    def grad(x):
        Y = X.ravel().copy()
        Y[free] = x
        return solver.grad_hess(Y.reshape(-1, 2), 0.0)[1][free]

    x0 = X.ravel()[free]
    h = 1e-6 * solver.mesh.bbox_diagonal
    H = np.empty((len(free), len(free)))
    for i in range(len(free)):
        e = np.zeros(len(free))
        e[i] = h
        H[:, i] = (grad(x0 + e) - grad(x0 - e)) / (2 * h)
    return 0.5 * (H + H.T), grad(x0)


def _assert_verified(solver, res, T_given, handles):
    """Checks 1-3 directly, and for ARAP checks 4-5 on a finite-difference Hessian (independent of the LDLᵀ)."""
    mesh = solver.mesh
    d = mesh.bbox_diagonal
    assert np.isfinite(res.energy)
    assert np.abs(res.X[handles] - T_given).max() <= 1e-12 * d
    J = mesh.jacobians(res.X)
    if solver.barrier:
        assert np.all(np.linalg.det(J) > 0)
    if solver.energy == "arap":
        H, g = _fd_hessian_of_gradient(solver, res.X)
        lam = np.linalg.eigvalsh(H)
        assert lam[0] >= -1e-6 * lam[-1]  # a local minimum, not a saddle
        dec = g @ np.linalg.solve(H + 1e-12 * lam[-1] * np.eye(len(g)), g) / 2
        assert dec <= 1e-5 * max(res.energy, 1e-12 * mesh.areas.sum())
    else:  # S-ARAP's kink defeats a finite-difference Hessian: no move of a random direction descends
        rng = np.random.default_rng(0)
        for _ in range(5):
            D = rng.normal(size=res.X.shape)
            D[solver.handles] = 0
            D *= 1e-5 * d / np.abs(D).max()
            for sgn in (1, -1):
                assert solver.energy_of(res.X + sgn * D) >= res.energy * (1 - 1e-9)
        # nor does a re-solve from such a move (star 3273 ended 1.6e-5 lower; 550 random stars: at most 2.3e-8)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)
            again = solver.solve(T_given, X0=res.X + D)
        assert again.energy >= res.energy * (1 - 1e-7) - 1e-12 * mesh.areas.sum()  # E = 0 up to round-off


# ---------------------------------------------------------------- property tests
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 10_000),
    n_handles=st.integers(2, 5),
    n_dup=st.integers(0, 2),
    energy=st.sampled_from(["arap", "sarap"]),
    scale=st.floats(0.0, 0.08),
)
def test_random_stars_any_handle_order(seed, n_handles, n_dup, energy, scale):
    shape = star_with_hole(seed)
    mesh = shape.mesh
    rng = np.random.default_rng(seed + 1)
    h = rng.choice(mesh.n_vertices, n_handles, replace=False)  # random subset, random order
    h = np.concatenate([h, rng.choice(h, n_dup)])  # duplicates ...
    T = mesh.V[h] + scale * mesh.bbox_diagonal * rng.normal(size=(len(h), 2))
    first = {v: k for k, v in reversed(list(enumerate(h)))}
    T = T[[first[v] for v in h]]  # ... carrying equal targets
    perm = rng.permutation(len(h))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        a = Solver(mesh, h, energy).solve(T)
        b = Solver(mesh, h[perm], energy).solve(T[perm])
    assert np.abs(a.X - b.X).max() <= 1e-10 * mesh.bbox_diagonal
    assert a.converged == b.converged
    event(f"{energy} converged={a.converged}")
    if a.converged:
        _assert_verified(Solver(mesh, h, energy), a, T, h)
    else:
        assert "check failed" in a.reason or "limit" in a.reason or "flip" in a.reason


# ---------------------------------------------------------------- independent reference
def test_agrees_with_finite_difference_newton():
    """A from-scratch reference on a 5×5 grid (32 triangles): Newton with finite-difference gradient and Hessian
    of an energy computed with numpy's SVD."""
    x, y = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 0.8, 5))
    V = np.column_stack([x.ravel(), y.ravel()])
    F = []
    for i in range(4):
        for j in range(4):
            a, b, c, d = 5 * i + j, 5 * i + j + 1, 5 * (i + 1) + j, 5 * (i + 1) + j + 1
            F += [[a, b, d], [a, d, c]]
    F = np.array(F)
    mesh = dop.geometry.mesh.Mesh(V, F)
    assert len(F) == 32
    h = np.array([24, 0, 4])  # unsorted on purpose
    T = V[h] + [[0.15, 0.1], [0.0, 0.0], [0.05, -0.05]]
    for energy in ("arap", "isometric"):
        ours = dop.solve(mesh, h, T, energy)
        assert ours.converged
        free = np.setdiff1d(np.arange(len(V)), h)
        X = V.copy()
        X[h] = T
        X[free] = ours.X[free] + 0.01 * np.sin(7 * V[free])  # a nearby start, not ours

        def E(z, X=X, free=free, energy=energy):
            Y = X.copy()
            Y[free] = z.reshape(-1, 2)
            return _energy_from_scratch(V, F, Y, energy)

        z = X[free].ravel()
        for _ in range(4):
            n, eps, hh = len(z), 1e-6, 1e-4
            g = np.array([(E(z + eps * e) - E(z - eps * e)) / (2 * eps) for e in np.eye(n)])
            H = np.empty((n, n))
            for i in range(n):
                ei = hh * np.eye(n)[i]
                for j in range(i, n):
                    ej = hh * np.eye(n)[j]
                    d2 = E(z + ei + ej) - E(z + ei - ej) - E(z - ei + ej) + E(z - ei - ej)
                    H[i, j] = H[j, i] = d2 / (4 * hh * hh)
            p = -np.linalg.solve(H, g)
            t = 1.0
            while E(z + t * p) > E(z) and t > 1e-8:
                t /= 2
            z = z + t * p
        ref = X.copy()
        ref[free] = z.reshape(-1, 2)
        assert ours.energy == pytest.approx(E(z), rel=1e-7)
        assert ours.energy == pytest.approx(_energy_from_scratch(V, F, ours.X, energy), rel=1e-12)
        assert np.abs(ours.X - ref).max() <= 1e-5 * mesh.bbox_diagonal


# ---------------------------------------------------------------- saddles
def _mirrored(shape):
    V = shape.mesh.V.copy()
    V[:, 1] = V[:, 1].max() + V[:, 1].min() - V[:, 1]
    return dop.geometry.mesh.Mesh(V, shape.mesh.F[:, ::-1])


def test_bar_pushed_in_buckles_both_ways_not_the_saddle():
    """The bar pushed straight in along its axis from the rest pose: the symmetric state is a saddle (energy
    0.0229 against 0.0087 buckled); both branches are found and the lower kept. Their energies differ by
    3.0e-3 (relative), the mesh's own asymmetry: on the mirrored mesh the two branches swap, same energies."""
    bar = dop.shapes.load("bar")
    T = bar.targets(bar.P_moving + [[-0.26, 0.0]])
    mid = np.argmin(np.abs(bar.mesh.V[:, 0] - 0.5) + np.abs(bar.mesh.V[:, 1] - bar.mesh.V[:, 1].mean()))
    out = {}
    Tm = T.copy()
    Tm[:, 1] = bar.mesh.V[:, 1].max() + bar.mesh.V[:, 1].min() - T[:, 1]  # the mirror image of the targets
    for name, mesh, targets in (("bar", bar.mesh, T), ("mirrored", _mirrored(bar), Tm)):
        res = Solver(mesh, bar.handles, "sarap").solve(targets)
        assert res.converged and "escape" in res.start
        saddle = [E for lab, E, ok in res.candidates if lab == "rest"]
        branches = sorted(E for lab, E, ok in res.candidates if "escape" in lab and ok)
        assert len(saddle) == 1 and len(branches) == 2
        assert max(branches) < 0.5 * saddle[0]
        assert res.energy == branches[0]
        out[name] = (branches, np.sign(res.X[mid, 1] - mesh.V[mid, 1]))
    (b1, s1), (b2, s2) = out["bar"], out["mirrored"]
    np.testing.assert_allclose(b1, b2, rtol=1e-7)
    assert s1 == -s2  # the lower branch buckles the other way on the mirror image: the mesh decides
    asym = (b1[1] - b1[0]) / b1[0]
    assert 1e-4 < asym < 1e-2  # measured 3.0e-3


def test_saddle_is_not_converged_without_escapes():
    bar = dop.shapes.load("bar")
    solver = Solver(bar.mesh, bar.handles, "sarap")
    solver.max_escapes = 0
    with pytest.warns(NotConvergedWarning, match="saddle"):
        res = solver.solve(bar.targets(bar.P_moving + [[-0.26, 0.0]]))
    assert not res.converged and "negative eigenvalue" in res.reason


# ---------------------------------------------------------------- regressions, one per case of the issue
@pytest.mark.parametrize("energy", ["arap", "sarap"])
def test_handle_order_bar(energy):
    bar = dop.shapes.load("bar")
    V = bar.mesh.V
    h = [39, 0]
    T = V[h] + [[0.1, 0.05], [0.0, 0.0]]
    a = dop.solve(bar.mesh, h, T, energy)
    b = dop.solve(bar.mesh, h[::-1], T[::-1], energy)
    assert a.converged and b.converged
    assert np.abs(a.X[h] - T).max() <= 1e-12 * bar.mesh.bbox_diagonal
    assert np.abs(a.X - b.X).max() <= 1e-10 * bar.mesh.bbox_diagonal


@pytest.mark.parametrize("energy", ["arap", "sarap"])
def test_handle_order_star_with_hole(energy):
    shape = star_with_hole(7)
    h = np.array([4, 0, 2])
    T = shape.mesh.V[h] + 0.05 * shape.mesh.bbox_diagonal * np.array([[1.0, 0.5], [-0.5, 0.2], [0.0, -1.0]])
    res = dop.solve(shape.mesh, h, T, energy)
    assert res.converged
    assert np.abs(res.X[h] - T).max() <= 1e-12 * shape.mesh.bbox_diagonal
    lb = dop.variational.solve_lbfgs(shape.mesh, h, T, energy, tol=1e-14)
    assert np.abs(lb.X[h] - T).max() <= 1e-12 * shape.mesh.bbox_diagonal


def test_star_trained_with_unsorted_handles_reproduces_its_samples():
    """Proposition 1 (TPS reproduces every training deformation) with handles given as [0, 4, 8, 6, 12]."""
    base = star_with_hole(3, n_vertices=80)
    h = np.array([0, 4, 8, 6, 12])
    moving = np.array([True, True, False, True, False])
    shape = dop.shapes.Shape("star", base.mesh, h, moving, [{"kind": "disc", "radius": 0.1}] * 3)
    rng = np.random.default_rng(0)
    samples = shape.P_moving + 0.04 * base.mesh.bbox_diagonal * rng.normal(size=(10,) + shape.P_moving.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op, rec = dop.train(shape, "arap", "tps", samples=samples, n_jobs=1, cache=False, progress=False)
    assert rec.converged.all()
    for q, X in zip(samples, rec.X):
        assert np.abs(X[h] - shape.targets(q)).max() <= 1e-12 * base.mesh.bbox_diagonal
        assert np.abs(op(q) - X).max() <= 1e-6 * base.mesh.bbox_diagonal


def test_adjacent_handles_sent_to_one_point_is_not_converged():
    bar = dop.shapes.load("bar")
    a, b = bar.mesh.F[0][:2]
    with pytest.warns(NotConvergedWarning):
        res = dop.solve(bar.mesh, [a, b], bar.mesh.V[[a, a]], "sarap")
    assert not res.converged and "collapse" in res.reason


def test_target_at_1e300_is_rejected():
    bar = dop.shapes.load("bar")
    with pytest.raises(ValueError, match="overflow"):
        dop.solve(bar.mesh, [0, 39], [[1e300, 0.0], bar.mesh.V[39]], "sarap")


def test_sarap_reports_eq11_optimum_not_the_smoothed_one():
    """The default schedule ends on Eq. (11) itself: within 1e-7 (relative) of a μ → 1e-13 reference minimum
    (measured up to 2.3e-8; the μ = 1e-5 optimum alone was up to 3.9e-6 above, on the aleph and the gingerbread
    man), and far closer than the μ = 1e-5 optimum."""
    s = dop.shapes.load("gingerbread", n_vertices=400)
    rng = np.random.default_rng(3)
    T = s.targets(s.P_moving + rng.normal(scale=0.06 * s.mesh.bbox_diagonal, size=s.P_moving.shape))
    res = Solver(s.mesh, s.handles, "sarap").solve(T)
    assert res.converged and res.flips == 0
    assert Solver(s.mesh, s.handles, "sarap").mu_schedule[-1] == 0.0
    ref = Solver(s.mesh, s.handles, "sarap", smoothing=(1e-7, 1e-9, 1e-11, 1e-13)).solve(T, X0=res.X, tol=1e-14)
    assert res.energy <= ref.energy * (1 + 1e-7)
    smoothed = Solver(s.mesh, s.handles, "sarap")
    smoothed.mu_schedule = (1e-5,)  # the former default: the smoothed optimum, reported as the answer
    old = smoothed.solve(T)
    assert res.energy - ref.energy <= 0.1 * (old.energy - ref.energy)


@pytest.mark.parametrize("s", [0.7, 1.4])
def test_uniform_scaling_holds_every_triangle_on_the_kink(s):
    """Boundary pinned on s·V: X = s·V is the minimum, every triangle conformal (on Eq. (11)'s kink, held) with no
    force pulling it off (constant isotropic stress is in equilibrium), E = area·((s−1)² + (1/s−1)²) exactly."""
    mesh = star_with_hole(5).mesh
    b = np.concatenate(mesh.boundary_loops())
    solver = Solver(mesh, b, "sarap")
    T = s * mesh.V[b]
    check = solver.verify(s * mesh.V, solver.targets_of(T))
    assert check.ok
    # the multipliers: every held triangle's pull is inside its cone and its offset is 0, so the Fenchel gap is 0
    E, g, data, local = solver.grad_hess(s * mesh.V, 0.0, project=False, kink=dop.variational.verify.KINK)
    p = solver.newton_direction(g[solver.free], data, rel_shift=dop.variational.verify.INERTIA_SHIFT)
    verify = dop.variational.verify
    gain, worst, D, pulled, offset = verify.kink_pull(solver, s * mesh.V, local, p, verify.KINK)
    assert gain == 0.0 and D is None and len(pulled) == 0 and offset <= 1e-12 * E
    S = dop.variational.planar.svd_frame(mesh.jacobians(s * mesh.V))[0]
    assert dop.variational.planar.on_kink(S, dop.variational.verify.KINK).all()
    res = solver.solve(T)
    assert res.converged and res.start == "rest"
    assert np.abs(res.X - s * mesh.V).max() <= 1e-6 * mesh.bbox_diagonal  # held triangles keep offsets (see Solver)
    # held triangles keep the offset from the kink they had when first held (up to KINK): measured 5e-9 and 1.4e-7
    assert res.energy == pytest.approx(mesh.areas.sum() * ((s - 1) ** 2 + (1 / s - 1) ** 2), rel=1e-6)
    with pytest.raises(AssertionError):  # a perturbed point is not a minimum: the check can fail
        assert solver.verify(s * mesh.V + _interior_bump(solver, 1e-3), solver.targets_of(T)).ok


def _pinned_near_conformal(seed, s, noise):
    mesh = star_with_hole(seed).mesh
    b = np.concatenate(mesh.boundary_loops())
    T = s * mesh.V[b] + noise * mesh.bbox_diagonal * np.random.default_rng(seed).normal(size=(len(b), 2))
    return mesh, b, T


@pytest.mark.parametrize("noise", [1e-6, 1e-4])
@pytest.mark.parametrize("s", [0.7, 1.4])
@pytest.mark.parametrize("seed", [5, 6, 7, 8])
def test_near_conformal_pinned_boundary_ends_within_verify_tol_of_the_minimum(seed, s, noise):
    """Boundary pinned on s·V plus noise: nearly every triangle is within KINK of the kink, and more of them than the
    free dofs allow cannot all be conformal. Holding them with frozen offsets used to report converged up to 2.4e-6
    above the minimum (check 4 ignored what the offsets cost); now the smoothing continues until the held point's
    Fenchel gap is small, and check 4 certifies it (measured: 16/16 converged, within 1.4e-8 of a μ → 1e-13
    reference). The reference and a re-solve from a 1e-5 move both bound the minimum from this side."""
    mesh, b, T = _pinned_near_conformal(seed, s, noise)
    solver = Solver(mesh, b, "sarap")
    a = solver.solve(T)
    assert a.converged
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.variational.NotConvergedWarning)
        ref = Solver(mesh, b, "sarap", smoothing=(1e-7, 1e-9, 1e-11, 1e-13)).solve(T, X0=a.X, tol=1e-14)
        again = solver.solve(T, X0=a.X + _interior_bump(solver, 1e-5))
    assert ref.energy >= a.energy * (1 - 1e-6) and again.energy >= a.energy * (1 - 1e-6)


def test_frozen_offsets_are_not_certified_and_the_continuation_slides_them(monkeypatch):
    """Without the continuation (the previous solver), held triangles keep their offsets: check 4 now rejects that
    point ("kink", the offsets' cost); with it, the held triangles slide along the kink (their scale s and offsets
    change) to a point lower by more than verify_tol · E, which check 4 accepts."""
    mesh, b, T = _pinned_near_conformal(5, 0.7, 1e-6)
    solver = Solver(mesh, b, "sarap")
    monkeypatch.setattr(dop.variational.newton, "KINK_TARGET", np.inf)
    with pytest.warns(NotConvergedWarning, match="kink"):
        old = solver.solve(T)
    monkeypatch.undo()
    check = solver.verify(old.X, solver.targets_of(T))
    assert check.failed == "kink" and "offsets" in check.reason
    new = solver.solve(T)
    assert new.converged and "smoothing continued" in new.reason
    assert new.energy < old.energy * (1 - solver.verify_tol)
    en = dop.variational.planar
    S_old, S_new = (en.svd_frame(mesh.jacobians(X))[0] for X in (old.X, new.X))
    held = en.on_kink(S_old, dop.variational.verify.KINK) & en.on_kink(S_new, dop.variational.verify.KINK)
    assert held.sum() > len(S_old) // 2
    slid = np.abs(S_new[held].mean(1) - S_old[held].mean(1)) > 1e-9
    assert slid.sum() > held.sum() // 2  # held triangles moved along the kink (their conformal scale changed)


def test_the_smoothing_certificate_passes_where_the_held_multipliers_are_not_unique_and_rejects_a_bump():
    """With noise 1e-4 more triangles are held than the free dofs can keep conformal: the Fenchel bound with the
    solver's split of the multipliers stays loose (> verify_tol) at the minimum, and check 4 accepts the smoothed
    solve's certificate instead; a 1e-4 bump of the same point is rejected by both."""
    from defop.variational import kink

    mesh, b, T = _pinned_near_conformal(5, 0.7, 1e-4)
    solver = Solver(mesh, b, "sarap")
    a = solver.solve(T)

    def gap(solver, X):
        return dop.variational.verify.kink_gap(solver, X, dop.variational.newton.KINK_TARGET * solver.verify_tol)

    assert a.converged and gap(solver, a.X) > solver.verify_tol
    mu = kink.certificate_mu(a.energy, mesh.areas.sum(), solver.verify_tol)
    assert 0 < mu * mesh.areas.sum() <= 0.3 * solver.verify_tol * a.energy * (1 + 1e-12)
    bumped = a.X + _interior_bump(solver, 1e-4)
    check = solver.verify(bumped, solver.targets_of(T))
    assert not check.ok and check.failed in ("decrement", "kink")


def test_fenchel_gap_is_zero_exactly_at_equilibrium_on_the_cone():
    """kink.fenchel_gap against a brute-force conjugate: A φ(a) − P·a + max_b (P·b − A φ(b)) over a grid of b."""
    from defop.variational import kink
    from defop.variational import planar as en

    rng = np.random.default_rng(0)
    for _ in range(20):
        s, A = rng.uniform(0.5, 2.0), rng.uniform(0.1, 2.0)
        r, kappa = en.kink_radius(np.array([[s, s]]))
        a = abs(rng.normal()) * 1e-2 * rng.integers(0, 2)
        P = rng.normal(size=2) * A * r[0] * rng.uniform(0.2, 2.0)
        S = np.array([[s + a / np.sqrt(2), s - a / np.sqrt(2)]])
        offset, excess = kink.fenchel_gap(S, np.array([True]), np.array([A]), _on_modes(P[None]))
        nb = np.linspace(0.0, 3.0, 300001)  # the conjugate's maximiser lies along P: a fine search over its length
        r_s, k_s = en.kink_radius(np.array([[(S[0, 0] + S[0, 1]) / 2] * 2]))
        conj = np.max(nb * np.hypot(*P) - A * (r_s[0] * nb + k_s[0] * nb**2 / 2))
        assert excess[0] == pytest.approx(conj, rel=1e-6, abs=1e-9 * A)
        B = rng.normal(size=(1000, 2)) * rng.uniform(0, 2, (1000, 1))  # and no other direction does better
        assert np.all(B @ P - A * (r_s[0] * np.hypot(*B.T) + k_s[0] * np.hypot(*B.T) ** 2 / 2) <= excess[0] + 1e-12)
        assert offset[0] + excess[0] >= -1e-12
    # on the kink with a pull inside the cone, and off it at equilibrium, the gap is zero
    S = np.array([[0.7, 0.7], [0.7 + 1e-3, 0.7 - 1e-3]])
    r, kappa = en.kink_radius(S)
    a = np.sqrt(2) * 1e-3
    P = np.array([[0.5 * r[0], 0.3 * r[0]], [r[1] + kappa[1] * a, 0.0]])
    on = np.ones(2, dtype=bool)
    offset, excess = kink.fenchel_gap(S, on, np.ones(2), _on_modes(P))
    assert np.allclose(offset + excess, 0.0, atol=1e-15)
    P[1, 1] = 0.1  # a sideways pull off equilibrium: the gap opens
    assert sum(kink.fenchel_gap(S, on, np.ones(2), _on_modes(P)))[1] > 0


def _on_modes(P):
    """A force (k,2) on the two anti-conformal modes as a force on all four modes of planar.eigensystem."""
    F = np.zeros((len(P), 4))
    F[:, [1, 3]] = P
    return F


def _interior_bump(solver, size):
    D = np.random.default_rng(1).normal(size=solver.mesh.V.shape)
    D[solver.handles] = 0
    return D * size * solver.mesh.bbox_diagonal / np.abs(D).max()


def test_global_start_records_the_winner():
    bar = dop.shapes.load("bar")
    T = bar.targets(bar.P_moving + [[-0.26, 0.0]])
    solver = Solver(bar.mesh, bar.handles, "sarap")
    local = solver.solve(T)
    shifted = solver.solve(T, X0=local.X, start="global")
    assert shifted.converged and shifted.energy <= local.energy * (1 + 1e-12)
    assert shifted.start.startswith(("start 0", "rest"))
    assert {c[0].split(" > ")[0] for c in shifted.candidates} == {"start 0", "rest"}


# ---------------------------------------------------------------- bad input
def test_bad_handles_and_limits():
    bar = dop.shapes.load("bar")
    mesh = bar.mesh
    n = mesh.n_vertices
    with pytest.raises(ValueError, match="integer vertex indices; handle 0 is 1.7"):
        Solver(mesh, [1.7, 2.9])
    assert np.array_equal(Solver(mesh, [3.0, 7.0]).handles, [3, 7])  # integer-valued floats are accepted
    mask = np.zeros(n, bool)
    mask[[5, 2]] = True
    assert np.array_equal(Solver(mesh, mask).handles, [2, 5])
    with pytest.raises(ValueError, match="boolean handle mask"):
        Solver(mesh, mask[:-1])
    with pytest.raises(ValueError, match=f"out of range for a mesh of {n} vertices"):
        Solver(mesh, [0, n])
    with pytest.raises(ValueError, match="every one of the .* vertices is a handle"):
        Solver(mesh, np.arange(n))
    for kw in (dict(tol=-1.0), dict(tol=np.nan), dict(max_iter=0), dict(max_iter=2.5)):
        with pytest.raises(ValueError, match="tol|max_iter"):
            Solver(mesh, [0, 39], **kw)
    with pytest.raises(ValueError, match="tol"):
        Solver(mesh, [0, 39]).solve(mesh.V[[0, 39]], tol=-1)
    with pytest.raises(ValueError, match="two different targets"):
        Solver(mesh, [0, 39, 0]).solve(mesh.V[[0, 39, 39]])


def test_solve_best_skips_rejected_starts():
    bar = dop.shapes.load("bar")
    solver = Solver(bar.mesh, bar.handles, "sarap")
    T = bar.targets(bar.P_moving + [[0.0, 0.1]])
    flipped = bar.mesh.V * [-1.0, 1.0]
    res = solver.solve_best(T, starts=[flipped], rest=False)  # the only start is flipped: the rest pose is used
    assert res.converged and res.start == "rest"
    assert any(lab.startswith("start 0 (rejected") for lab, _, _ in res.candidates)
    first = solver.solve_best(T, starts=[None, res.X], keep="first")
    assert first.converged and first.start == "start 1" and first.iterations <= 3  # one per μ stage


def test_the_held_set_lives_below_newton_and_verify_keeps_its_names():
    """Issue 35: held_on_kink, kink_pull and kink_gap moved to :mod:`defop.variational.kink` (newton uses them and no
    longer imports verify, which imports newton); verify keeps the names. One shift: :mod:`.inertia`."""
    import importlib

    verify, kink, inertia = (importlib.import_module(f"defop.variational.{m}") for m in ("verify", "kink", "inertia"))
    for name in ("held_on_kink", "kink_pull", "kink_gap"):
        assert getattr(verify, name) is getattr(kink, name)
    assert verify.inertia_shift is inertia.inertia_shift and verify.INERTIA_SHIFT == inertia.INERTIA_SHIFT
    newton = importlib.import_module("defop.variational.newton")
    assert not hasattr(newton, "verify")
    assert "shift" not in inspect.signature(kink.newton_decrement).parameters  # the policy's, not the caller's
