"""The saddle between the bar's two minima: a mountain pass over the pinned mid-bar vertex.

The bar of Fig. 10 with its handle pushed in by 0.3 along its axis; the two minima are solved directly from the
rest pose bent up and down (no branch discovery). From the bent-up minimum the pinned profile climbs monotonically
to a critical point of problem (6) (reaction force ~1e-6 of the forces along the way) with one negative curvature
that keeps the kink-held triangles on Eq. (11)'s kink: a saddle, whose two descents end in the two minima. Check 5
of ``verify`` sees that negative curvature (its shift is taken from the median diagonal, not the mean, which the
held triangles' stiff modes dominate).
"""

import inspect

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import defop as dop
from defop.analysis import mountain_pass as sd
from defop.analysis.branches import one_moving
from defop.variational import kink
from defop.variational import problem as pb


@pytest.fixture(scope="module")
def bar():
    shape = one_moving(dop.shapes.load("bar"), 0)
    T = shape.targets(shape.P_moving + [-0.3, 0.0])
    S = dop.variational.solver.Solver(shape.mesh, shape.handles, "sarap")
    V = shape.mesh.V
    bump = np.sin(np.pi * (V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0]))
    minima = []
    for s in (1.0, -1.0):
        r = S.solve(T, X0=V + np.column_stack([0 * bump, s * 0.1 * bump]))
        assert r.converged
        minima.append((np.asarray(r.X), r.energy))
    x = int(np.argmin(np.linalg.norm(V - [0.5, 0.1], axis=1)))  # the mid-bar point of Fig. 10
    return shape, S, T, minima, x


@pytest.fixture(scope="module")
def climb(bar):
    shape, S, T, ((Xa, _), (Xb, _)), x = bar
    prof = sd.profile(S, T, x, Xa, float(Xb[x, 1]), 6)
    return prof, sd.refine_saddle(S, T, x, prof)


def test_two_distinct_minima(bar):
    shape, S, T, ((Xa, Ea), (Xb, Eb)), x = bar
    assert np.abs(Xa - Xb).max() > 0.3 * shape.mesh.bbox_diagonal
    assert Xa[x, 1] > 0.3 > -0.1 > Xb[x, 1]  # bent up, bent down
    assert abs(Ea - Eb) < 0.01 * Ea


def test_the_top_of_the_profile_is_a_critical_point_above_both_minima(bar, climb):
    _, _, _, ((_, Ea), (_, Eb)), _ = bar
    prof, saddle = climb
    assert prof.top is not None and prof.converged.all()
    assert np.linalg.norm(saddle.force) < 1e-4 * saddle.force_scale
    assert saddle.energy > 2.5 * max(Ea, Eb)
    assert saddle.energy >= prof.energies.max() - 1e-9


def test_the_profile_climbs_monotonically_to_the_saddle(climb):
    prof, saddle = climb
    E = prof.energies[: prof.top + 1]
    assert np.all(np.diff(E) > 0) and E[-1] < saddle.energy
    # E* has gradient f: the climb's energy is the integral of the reaction force
    dy = np.diff(prof.pins[: prof.top + 1, 1])
    f = prof.forces[: prof.top + 1, 1]
    assert np.allclose(np.diff(E), (f[1:] + f[:-1]) * dy / 2, rtol=0.1, atol=1e-5)


def test_one_negative_curvature_that_keeps_the_kink(bar, climb):
    shape, S, _, _, _ = bar
    saddle = climb[1]
    assert saddle.negative == 1 and saddle.curvature < -1e-3
    lam, D = sd.held_curvature(S, saddle.X)
    C = sd.held_constraints(S, saddle.X)
    assert C.shape[0] >= 2 and np.abs(C @ D.ravel()[S.free]).max() < 1e-12  # held offsets kept
    ts = shape.mesh.bbox_diagonal * np.logspace(-5, -2, 4)
    dE = sd.probe(S, saddle.X, D, ts)
    assert np.all(dE < 0)  # down from 1e-5 of the diagonal: no kink-held well around the saddle
    ratio = dE[:, 1:] / dE[:, :-1]
    assert np.all((ratio > 50) & (ratio < 200))  # quadratic: -|λ| t² / 2


def test_the_smooth_eigenvector_climbs_the_cone_first(bar, climb):
    shape, S, _, _, _ = bar
    saddle = climb[1]
    lam, v = sd.smooth_direction(S, saddle.X)
    assert lam < -1e-3
    ts = shape.mesh.bbox_diagonal * np.logspace(-5, -1.5, 8)
    dE = sd.probe(S, saddle.X, v, ts)
    assert dE[:, 1].min() > 0  # r‖a‖ of the held triangles first
    assert dE[:, -1].max() < 0  # then the negative curvature wins


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_random_directions_climb(bar, climb, seed):
    shape, S, _, _, _ = bar
    saddle = climb[1]
    D = np.random.default_rng(seed).normal(size=saddle.X.shape)
    D[S.handles] = 0.0
    dE = sd.probe(S, saddle.X, D / np.abs(D).max(), shape.mesh.bbox_diagonal * np.logspace(-6, -3, 4))
    assert np.all(dE > 0)


def test_the_two_descents_end_in_the_two_minima(bar, climb):
    shape, S, T, ((Xa, _), (Xb, _)), _ = bar
    saddle = climb[1]
    ends = sd.descents(S, T, saddle.X, sd.held_curvature(S, saddle.X)[1])
    dist = [[np.abs(e - m).max() / shape.mesh.bbox_diagonal for m in (Xa, Xb)] for e in ends]
    assert sorted(np.argmin(d) for d in dist) == [0, 1] and max(min(d) for d in dist) < 1e-5


def test_verify_rejects_the_saddle(bar, climb):
    # check 5's shift was 1e-8 · mean|diag| = 0.26 here, dominated by the held triangles' stiff modes (diagonal up to
    # 3.8e9, median 8.8): it hid the eigenvalue −1.9e-3 and verify accepted this saddle as a minimum
    _, S, T, _, _ = bar
    check = S.verify(climb[1].X, S.targets_of(T))
    assert not check.ok and check.failed == "saddle" and check.negative == 1
    assert climb[1].negative_shifted == 1 and not climb[1].verified and climb[1].converged  # a pinned minimum


@pytest.mark.skipif(not pb.HAVE_PARDISO, reason="pypardiso (the mkl extra) is not installed")
def test_verify_rejects_the_saddle_with_pardiso_too(bar, climb):
    # PARDISO reads the inertia from its own LDLᵀ, whose pivoting perturbs pivots below 1e-8 of the matrix's norm
    shape, _, T, _, _ = bar
    S = dop.variational.solver.Solver(shape.mesh, shape.handles, "sarap", backend="pardiso")
    check = S.verify(climb[1].X, S.targets_of(T))
    assert not check.ok and check.failed == "saddle" and check.negative == 1


def test_bad_input(bar):
    shape, S, T, ((Xa, _), (Xb, _)), x = bar
    with pytest.raises(ValueError, match="vertex must be a free vertex"):
        sd.profile(S, T, int(S.handles[0]), Xa, 0.0, 4)
    with pytest.raises(ValueError, match="steps must be an integer"):
        sd.mountain_pass(S, T, x, Xa, Xb, steps=2)
    with pytest.raises(ValueError, match="different heights"):
        sd.mountain_pass(S, T, x, Xa, Xa, steps=4)
    n = shape.mesh.n_vertices
    for vertex in (n, -1, 5.5, True, "3"):
        with pytest.raises(ValueError, match="vertex must be"):
            sd.mountain_pass(S, T, vertex, Xa, Xb)
    for steps in (np.inf, np.nan, 0, 2.5):
        with pytest.raises(ValueError, match="steps must be an integer"):
            sd.profile(S, T, x, Xa, 0.0, steps)
    for y_end in (np.nan, np.inf, "0", float(Xa[x, 1])):
        with pytest.raises(ValueError, match="y_end must"):
            sd.profile(S, T, x, Xa, y_end, 4)
    for X0 in (Xa[:-1], np.full_like(Xa, np.nan), Xa.tolist()[:3]):
        with pytest.raises(ValueError, match="X0"):
            sd.profile(S, T, x, X0, 0.0, 4)


def test_the_pass_refuses_a_tet_mesh():
    shape = dop.shapes.load("plank_3d", 165)
    S = dop.variational.solver.Solver(shape.mesh, shape.handles, "sarap")
    free = int(np.setdiff1d(np.arange(shape.mesh.n_vertices), shape.handles)[0])
    V = shape.mesh.V
    with pytest.raises(ValueError, match="triangle meshes"):
        sd.mountain_pass(S, shape.targets(shape.P_moving), free, V, V + 0.01)
    with pytest.raises(ValueError, match="triangle Jacobians"):
        sd.held_constraints(S, V)


def test_every_exact_factorisation_of_a_solve_takes_the_one_shift(bar):
    """One inertia-shift policy (issue 35): besides Newton's own steps (``newton_direction``'s default), every
    factorisation of a solve (check 5, the held set's pull in ``kink_active_set``, ``kink_gap``, the certificate)
    shifts by :func:`defop.variational.inertia.inertia_shift`. The kink code used ``INERTIA_SHIFT`` of the mean."""
    from defop.variational.inertia import INERTIA_SHIFT, inertia_shift

    shape, _, T, _, _ = bar
    S = dop.variational.solver.Solver(shape.mesh, shape.handles, "sarap")
    V = shape.mesh.V
    bump = np.sin(np.pi * (V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0]))
    shifts, solve = [], S.hessian.solve

    def spy(data, b, rel_shift, *rest):  # rest: a Newton step's re-use tolerance (ReducedHessian.solve)
        shifts.append((rel_shift, inertia_shift(S, data)))
        return solve(data, b, rel_shift, *rest)

    S.hessian.solve = spy
    assert S.solve(T, X0=V + np.column_stack([0 * bump, 0.1 * bump])).converged
    newton = inspect.signature(S.newton_direction).parameters["rel_shift"].default
    other = [(got, policy) for got, policy in shifts if got != newton]
    assert len(other) >= 2  # the held set's pull and check 5 at least
    assert all(got == policy for got, policy in other)
    assert max(policy for _, policy in other) < 1e-3 * INERTIA_SHIFT  # held triangles: the mean's shift is far larger


def test_the_held_hessian_at_the_saddle_shows_its_negative_curvature(bar, climb):
    """With the held triangles on the kink (the system of ``kink_active_set`` and ``kink_gap``), the one policy's
    shift keeps the saddle's negative eigenvalue that ``INERTIA_SHIFT`` of the mean hid."""
    from defop.variational.inertia import INERTIA_SHIFT, inertia_shift

    _, S, _, _, _ = bar
    E, g, data, _ = S.grad_hess(climb[1].X, 0.0, project=False, kink=S.kink_threshold)
    negative = {}
    for name, shift in (("old", INERTIA_SHIFT), ("one", inertia_shift(S, data))):
        S.newton_direction(g[S.free], data, rel_shift=shift)
        negative[name] = S.hessian.inertia()
    assert negative == {"old": 0, "one": 1}
    assert kink.newton_decrement(S, climb[1].X, 0.0)[2] == 1  # the certificate's factorisation
