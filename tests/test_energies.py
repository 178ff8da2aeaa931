"""Energies (Eq. 10, 11, isometric): closed forms, finite differences, PSD projection, flip-free step."""

from __future__ import annotations

import numpy as np
import pytest

from defop.variational import energies as en
from defop.variational import planar


def _jacobians(rng, n=300, spread=0.3, min_det=0.3):
    J = np.eye(2) + spread * rng.normal(size=(n, 2, 2))
    J = J[np.linalg.det(J) > min_det]
    _, S, _ = planar.signed_svd(J)
    return J[(S[:, 0] - S[:, 1]) > 1e-3]  # away from the Σ = σ kink of S-ARAP


def test_signed_svd_reconstructs_with_rotations():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(500, 2, 2))
    U, S, V = planar.signed_svd(J)
    assert np.allclose(U @ (S[:, :, None] * np.swapaxes(V, 1, 2)), J, atol=1e-12)
    assert np.allclose(np.linalg.det(U), 1) and np.allclose(np.linalg.det(V), 1)
    assert np.all(S[:, 0] >= np.abs(S[:, 1]))
    assert np.array_equal(np.sign(S[:, 1]), np.sign(np.linalg.det(J)))  # σ < 0 exactly when folded


def test_single_triangle_closed_forms():
    s = 1.5
    J = np.array([s * np.eye(2)])
    assert en.density(J, "arap") == pytest.approx([2 * (s - 1) ** 2])
    assert en.density(J, "sarap") == pytest.approx([(s - 1) ** 2 + (1 / s - 1) ** 2])
    assert en.density(J, "isometric") == pytest.approx([2 * s**2 + 2 / s**2])
    stretch = np.array([[[2.0, 0.0], [0.0, 0.5]]])  # Σ = 2, σ = 1/2: S-ARAP is symmetric in shrink/stretch
    assert en.density(stretch, "sarap") == pytest.approx([1.0 + 1.0])
    # the isometric family: p = 2 is the symmetric Dirichlet energy minus 4; large p tends to max(Σ, 1/σ)² − 1
    assert planar._psi_isometric_max(np.array([s]), np.array([s]), p=2)[0] == pytest.approx([2 * s**2 + 2 / s**2 - 4])
    assert planar._psi_isometric_max(np.array([2.0]), np.array([0.8]), p=400)[0] == pytest.approx([3.0], rel=1e-2)
    assert en.density(J, "isometric_exp") == pytest.approx([np.exp(en.EXP_SCALE * (2 * s**2 + 2 / s**2 - 4)) - 1])
    # max(Σ, 1/σ) does not see σ while Σ dominates: Σ = 2 costs the same with σ = 1 and σ = 1.9
    # (+0.16% at p = 64, +6.6% at p = 16; the symmetric Dirichlet energy, which sees each singular value
    # separately, rises +30% (ψ) or +84% (ψ − 4, its excess over the rest value))
    grow = np.array([np.diag([2.0, 1.0]), np.diag([2.0, 1.9])])
    iso_max, sym_dir = en.density(grow, "isometric_max"), en.density(grow, "isometric") - 4
    assert iso_max[1] / iso_max[0] - 1 == pytest.approx(0.00156, abs=1e-5)
    assert sym_dir[1] / sym_dir[0] - 1 == pytest.approx(0.839, abs=1e-3)
    reflect = np.array([[[1.0, 0.0], [0.0, -1.0]]])
    assert en.density(reflect, "arap") == pytest.approx([4.0])  # signed σ = -1 is penalised: (−1−1)²
    for energy in ("sarap", "isometric", "isometric_max", "isometric_exp"):
        assert en.density(reflect, energy) == [np.inf]  # barriers: a flipped triangle is reported as +inf


@pytest.mark.parametrize("energy", en.ENERGIES)
def test_rigid_motions_are_at_the_minimum(energy):
    th = np.linspace(0, 2 * np.pi, 7)
    R = np.stack([np.stack([np.cos(th), -np.sin(th)], -1), np.stack([np.sin(th), np.cos(th)], -1)], 1)
    psi, grad, _ = en.hessian(R, energy)
    assert np.allclose(psi, en.REST_VALUE[energy], atol=1e-12)
    assert np.allclose(grad, 0, atol=1e-12)


@pytest.mark.parametrize(
    "energy,mu",
    [("arap", 0), ("sarap", 0), ("sarap", 1e-3), ("isometric", 0), ("isometric_max", 0), ("isometric_exp", 0)],
)
def test_gradient_and_hessian_match_finite_differences(energy, mu):
    rng = np.random.default_rng(1)
    J = _jacobians(rng)
    psi, g, H = en.hessian(J, energy, project=False, mu=mu)
    h = 1e-6
    for k in range(4):
        dJ = np.zeros((len(J), 4))
        dJ[:, k] = h
        dJ = dJ.reshape(-1, 2, 2)
        fd_g = (en.density(J + dJ, energy, mu) - en.density(J - dJ, energy, mu)) / (2 * h)
        assert np.allclose(fd_g, g.reshape(-1, 4)[:, k], rtol=1e-6, atol=1e-6)
        fd_h = (en.gradient(J + dJ, energy, mu)[1] - en.gradient(J - dJ, energy, mu)[1]).reshape(-1, 4) / (2 * h)
        assert np.allclose(fd_h, H[:, :, k], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("energy", en.ENERGIES)
def test_projected_hessian_is_psd_and_exact_where_convex(energy):
    rng = np.random.default_rng(2)
    J = np.eye(2) + 0.8 * rng.normal(size=(500, 2, 2))
    if en.is_barrier(energy):
        J = J[np.linalg.det(J) > 0.05]
    _, _, H = en.hessian(J, energy, project=True)
    assert np.allclose(H, np.swapaxes(H, 1, 2))
    assert np.linalg.eigvalsh(H).min() >= -1e-9 * np.abs(H).max()
    # where no eigenvalue is clamped the projection changes nothing
    _, _, Hx = en.hessian(J, energy, project=False)
    ok = np.linalg.eigvalsh(Hx).min(axis=1) > 1e-9
    assert ok.sum() > 10 and np.allclose(H[ok], Hx[ok], atol=1e-9)


def test_smoothed_sarap_is_within_mu_of_eq_11():
    rng = np.random.default_rng(3)
    J = np.eye(2) + 0.4 * rng.normal(size=(1000, 2, 2))
    J = J[np.linalg.det(J) > 0.05]
    exact = en.density(J, "sarap")
    for mu in (1e-2, 1e-4):
        smooth = en.density(J, "sarap", mu)
        assert np.all(smooth <= exact + 1e-15) and np.all(smooth >= exact - mu - 1e-15)


def test_max_flip_free_step():
    J = np.array([np.eye(2)])
    dJ = np.array([[[-2.0, 0.0], [0.0, 0.0]]])  # det(I + t dJ) = 1 - 2t: linear, root 1/2
    assert en.max_flip_free_step(J, dJ, safety=1.0) == pytest.approx(0.5)
    dJ = np.array([[[-4.0, 0.0], [0.0, -4.0]]])  # (1 - 4t)^2: double root 1/4
    assert en.max_flip_free_step(J, dJ, safety=1.0) == pytest.approx(0.25, rel=1e-6)
    dJ = np.array([[[1.0, 0.0], [0.0, 1.0]]])  # growing: never flips
    assert en.max_flip_free_step(J, dJ) == 1.0
    rng = np.random.default_rng(4)
    J = np.eye(2) + 0.2 * rng.normal(size=(200, 2, 2))
    J = J[np.linalg.det(J) > 0]
    dJ = rng.normal(size=J.shape)
    t = en.max_flip_free_step(J, dJ, safety=1.0)
    ts = np.linspace(0, t * (1 - 1e-9), 200)
    assert all(np.linalg.det(J + s * dJ).min() > 0 for s in ts)
    if t < 1:
        assert np.linalg.det(J + t * 1.0001 * dJ).min() < 0


def test_unknown_energy():
    with pytest.raises(ValueError, match="unknown energy 'arapp'; known energies: arap, sarap, isometric, "):
        en.density(np.array([np.eye(2)]), "arapp")


@pytest.mark.parametrize("s", [0.4, 0.71, 0.95, 1.3, 2.5])
def test_kink_radius_is_the_slope_and_curvature_of_eq_11_off_a_conformal_jacobian(s):
    """On J = s·R, Eq. (11) along a unit anti-conformal direction a (any mix of the reflection and flip modes)
    grows like r·a + κ·a²/2: one-sided finite differences of ψ against kink_radius."""
    rng = np.random.default_rng(int(10 * s))
    R = planar._rot(np.array(rng.uniform(0, 2 * np.pi)))
    Z = planar._rot(np.array(rng.uniform(0, 2 * np.pi))) @ np.diag([1.0, -1.0]) / np.sqrt(2)  # unit, anti-conformal
    r, kappa = planar.kink_radius(np.array([[s, s]]))
    h = 1e-5
    psi = en.density(np.stack([s * R + t * Z for t in (0.0, h, 2 * h)]), "sarap")
    slope = (-3 * psi[0] + 4 * psi[1] - psi[2]) / (2 * h)  # one-sided, second order
    curv = (psi[0] - 2 * psi[1] + psi[2]) / h**2  # first order
    assert slope == pytest.approx(r[0], rel=1e-7, abs=1e-9)
    assert curv == pytest.approx(kappa[0], rel=1e-4)
    assert r[0] >= 0 and kappa[0] >= 15 / 16
