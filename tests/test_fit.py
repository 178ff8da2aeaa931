"""Problem (8): Propositions 1 and 2, the rest pose, and what bad input gets."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import defop as dop


@pytest.fixture(scope="module")
def data():
    """A U shape with synthetic, smooth, non-linear "ground truth" that interpolates the handles."""
    s = dop.shapes.load("u_shape", n_vertices=300)
    solver = dop.variational.Solver(s.mesh, s.handles, "arap")
    bump = np.sin(3 * s.mesh.V[:, 0]) * np.cos(2 * s.mesh.V[:, 1])
    bump = bump - solver.extend(bump[solver.handles, None] * [1.0, 0.0])[:, 0]  # zero at the handles

    def truth(Q):
        X = []
        for q in Q:
            T = s.targets(q)
            z = np.sin(4 * np.sum((q - s.P_moving) ** 2))  # not a polynomial in Q
            linear = solver.extend(T[np.argsort(s.handles)] - s.mesh.V[solver.handles])
            X.append(s.mesh.V + linear + 0.3 * z * np.column_stack([bump, -bump]))
        return np.array(X)

    rng = np.random.default_rng(0)
    Qtr, Qte = dop.training.sampling.sample_shape(s, 40, rng), dop.training.sampling.sample_shape(s, 30, rng)
    return s, Qtr, truth(Qtr), Qte, truth(Qte)


@pytest.mark.parametrize("spatial", ["hat", "reduced"])
@pytest.mark.parametrize("basis", ["linear", "quadratic", "cubic", "tps"])
def test_rest_pose_and_handles_at_untrained_Q(data, basis, spatial):
    s, Qtr, Xtr, Qte, _ = data
    op = dop.operator.fit.fit_shape(s, Qtr, Xtr, basis, spatial, k=30)
    assert np.abs(op(s.P_moving) - s.mesh.V).max() < 1e-10  # (8b): D(x, P) = x
    D = op(Qte)  # Proposition 2: handles interpolated at random untrained Q
    T = np.array([s.targets(q) for q in Qte])
    assert np.abs(D[:, s.handles] - T).max() < 1e-8


def test_proposition_1_tps_interpolates_the_training_deformations(data):
    s, Qtr, Xtr, _, _ = data
    op = dop.operator.fit.fit_shape(s, Qtr, Xtr, "tps", "hat")
    assert np.abs(op(Qtr) - Xtr).max() < 1e-8
    assert op.handle_basis.size == 1 + 2 * s.n_moving + len(Qtr) + 1  # the rest pose is a centre too


def test_richer_bases_fit_better(data):
    s, Qtr, Xtr, Qte, Xte = data
    err = {
        b: dop.analysis.approximation_error(dop.operator.fit.fit_shape(s, Qtr, Xtr, b), Qte, Xte)
        for b in ("linear", "quadratic", "cubic", "tps")
    }
    assert err["quadratic"] < 0.5 * err["linear"]
    assert err["tps"] < 0.5 * err["linear"]  # (cubic overfits 40 samples with 35 functions: no claim here)


def test_the_reduced_fit_is_the_projection_of_the_hat_fit(data):
    """With Φ reduced, the fit equals the hat fit projected on span Φ, up to the handle constraint."""
    s, Qtr, Xtr, Qte, _ = data
    hat = dop.operator.fit.fit_shape(s, Qtr, Xtr, "quadratic", "hat")
    red = dop.operator.fit.fit_shape(s, Qtr, Xtr, "quadratic", "reduced", k=60)
    rel = np.abs(red(Qte) - hat(Qte)).max() / s.mesh.bbox_diagonal
    assert rel < 0.02


def test_too_few_samples_says_the_minimum(data):
    s, Qtr, Xtr, _, _ = data
    msg = r"cubic basis \(\|Ψ\| = 35\) needs at least 35 samples with the rest pose \(34 besides it\)"
    with pytest.raises(ValueError, match=msg):
        dop.operator.fit.fit_shape(s, Qtr[:20], Xtr[:20], "cubic")
    with pytest.raises(ValueError, match="tps basis needs at least 6 samples"):
        dop.operator.fit.fit_shape(s, Qtr[:3], Xtr[:3], "tps")


def test_bad_shapes_and_nan(data):
    s, Qtr, Xtr, _, _ = data
    with pytest.raises(ValueError, match=r"samples must have shape \(m, 2, 2\)"):
        dop.operator.fit.fit_shape(s, Qtr[:, :1], Xtr, "linear")
    with pytest.raises(ValueError, match="one deformation per sample"):
        dop.operator.fit.fit_shape(s, Qtr, Xtr[:-1], "linear")
    bad = Xtr.copy()
    bad[3, 7, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        dop.operator.fit.fit_shape(s, Qtr, bad, "linear")
    with pytest.raises(ValueError, match=rf"samples 0 and {len(Qtr)} are the same handle configuration"):
        dop.operator.fit.fit_shape(s, np.concatenate([Qtr, Qtr[:1]]), np.concatenate([Xtr, Xtr[:1]]), "tps")


def test_fit_time_is_the_fastest_refit_and_needs_ground_truth():
    s = dop.shapes.load("bar")
    Q = dop.training.sampling.sample_shape(s, 6, np.random.default_rng(1))
    X = np.array([s.mesh.V + 0.01 * k for k in range(6)])  # any data: only the timing is under test
    t = dop.analysis.metrics.fit_time(s, Q, X, "linear", repeats=3)
    assert 0 < t < 10
    with pytest.raises(ValueError, match="needs the ground truths"):
        dop.analysis.metrics.fit_time(s, Q, None, "linear")


def test_symmetric_tps_path_equals_the_general_null_space_method():
    """TPS interpolation through the positive definite H = Qnᵀ K Qn gives the same G, β as the LU path."""
    from defop.operator import fit as F
    from defop.operator import handle_bases as hb

    rng = np.random.default_rng(4)
    P = rng.standard_normal((3, 2))
    Qs = np.concatenate([P[None], P + 0.3 * rng.standard_normal((40, 3, 2))])
    psi = hb.make_basis("tps", P, centers=Qs, scale=0.5)
    S = psi.evaluate_z(psi.z(Qs))
    A = np.vstack([S[:1], psi.side_conditions()])
    G1, b1, r1 = F.solve_structure(S, A)
    G2, b2, r2 = F.solve_structure_tps(S, psi.dim)
    assert r1 == r2 == len(Qs) - 1
    assert np.abs(G1 - G2).max() <= 1e-9 * np.abs(G1).max()
    assert np.abs(b1 - b2).max() <= 1e-9 * np.abs(b1).max()


@pytest.mark.parametrize("basis, spatial", [("tps", "hat"), ("quadratic", "hat"), ("tps", "reduced")])
def test_fitted_W_satisfies_the_constraints_the_operator_builds_on(data, basis, spatial):
    # DefOp's (★) evaluates x + δψ W_F + (Q − P) on the handles: that equals Ψ(Q) W exactly when the fit
    # met (8b) Ψ(P) W = x and (8c) W's handle columns are the handles' linear coefficients
    s, Qtr, Xtr, Qte, _ = data
    op = dop.operator.fit.fit_shape(s, Qtr, Xtr, basis, spatial, k=30)
    diag = s.mesh.bbox_diagonal
    assert np.abs(op.psi(s.P_moving) @ op.W - s.mesh.V.ravel()).max() <= 1e-10 * diag  # (8b)
    Wh = op.W.reshape(op.W.shape[0], -1, 2)[:, op.handles]
    for j, h in enumerate(np.flatnonzero(op.moving)):
        for c in range(2):
            assert np.abs(Wh[:, h, c] - op.handle_basis.linear_coefficients(j, c)).max() <= 1e-9 * diag
    # so Ψ(Q) W, the paper's Eq. (3) as fitted, and the evaluated (★) agree away from the handles too
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", dop.operator.ExtrapolationWarning)
        D = op(Qte)
    ref = (op.psi(Qte) @ op.W).reshape(D.shape)
    assert np.abs(D - ref).max() <= 1e-9 * diag
