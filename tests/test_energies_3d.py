"""3×3 closed forms of the energies (issue 27 §2): values, derivatives, eigensystem, kinks, cubic step, references."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import reference3d as r3  # tests/ is on sys.path (rootdir conftest)
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from defop.variational import energies as en
from defop.variational import planar
from defop.variational import volumetric as vo

ENERGIES = en.ENERGIES
BARRIERS = [e for e in ENERGIES if en.is_barrier(e)]
_entries = st.floats(-0.45, 0.45, allow_nan=False, allow_infinity=False)
perturbations = hnp.arrays(float, (3, 3), elements=_entries)
rotation_params = hnp.arrays(float, (4,), elements=st.floats(-1, 1, allow_nan=False)).filter(
    lambda q: np.linalg.norm(q) > 0.1
)


def _rotation(q):
    """Rotation matrix of the quaternion q (normalised)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _away_from_kinks(J, min_det=0.2, min_gap=2e-2):
    S = vo.signed_svd(J)[1]
    return (np.linalg.det(J) > min_det) & (S[:, 0] - S[:, 1] > min_gap) & (S[:, 1] - S[:, 2] > min_gap)


def _random_jacobians(seed, n=200, spread=0.3):
    J = np.eye(3) + spread * np.random.default_rng(seed).normal(size=(n, 3, 3))
    return J[_away_from_kinks(J)]


def _unit(k):
    E = np.zeros(9)
    E[k] = 1.0
    return E.reshape(3, 3)


# ---------------------------------------------------------------------------------------------- signed SVD
@given(A=perturbations, scale=st.floats(0.1, 3.0), reflect=st.booleans())
def test_signed_svd_reconstructs_with_rotations(A, scale, reflect):
    J = scale * (np.eye(3) + 2 * A) @ np.diag([1.0, 1.0, -1.0 if reflect else 1.0])
    assume(abs(np.linalg.det(J)) > 1e-6)
    U, S, V = vo.signed_svd(J[None])
    assert np.allclose(U[0] @ np.diag(S[0]) @ V[0].T, J, atol=1e-12 * (1 + np.abs(J).max()))
    assert np.allclose(np.linalg.det(U), 1) and np.allclose(np.linalg.det(V), 1)
    assert S[0, 0] >= S[0, 1] >= abs(S[0, 2])
    assert np.sign(S[0, 2]) == np.sign(np.linalg.det(J))  # σ₃ < 0 exactly when inverted


def test_bad_jacobians_are_rejected():
    with pytest.raises(ValueError, match=r"J must be an \(m,3,3\) array of 3×3 Jacobians, got shape \(3, 3\)"):
        vo.density(np.eye(3), "arap")
    with pytest.raises(ValueError, match="J must be an"):
        vo.signed_svd(np.zeros((4, 2, 2)))
    with pytest.raises(ValueError, match="J must be finite"):
        vo.density(np.full((1, 3, 3), np.nan), "arap")
    with pytest.raises(ValueError, match="unknown energy 'arapp'"):
        vo.density(np.eye(3)[None], "arapp")
    with pytest.raises(ValueError, match="det J > 0"):
        vo.max_flip_free_step(-np.eye(3)[None], np.eye(3)[None])
    with pytest.raises(ValueError, match="dJ must have the shape of J"):
        vo.max_flip_free_step(np.eye(3)[None], np.zeros((2, 3, 3)))


# ---------------------------------------------------------------------------------------------- values
def test_closed_form_values():
    s = 1.5
    J = np.array([s * np.eye(3)])
    u, v = (s - 1) ** 2, (1 / s - 1) ** 2
    assert vo.density(J, "arap") == pytest.approx([3 * u])
    assert vo.density(J, "sarap") == pytest.approx([u + (u + v) / 2 + v])
    assert vo.density(J, "isometric") == pytest.approx([3 * s**2 + 3 / s**2])
    assert vo.density(J, "isometric_exp") == pytest.approx([np.exp(en.EXP_SCALE * (3 * s**2 + 3 / s**2 - 6)) - 1])
    stretch = np.array([np.diag([2.0, 1.0, 0.5])])  # the docstring's formula on σ = (2, 1, ½)
    assert vo.density(stretch, "sarap") == pytest.approx([1.0 + 0.0 + 1.0])
    assert vo.density(np.array([np.diag([0.5, 2.0, 1.0])]), "sarap") == pytest.approx([2.0])  # order of σ is free
    # isometric_max tends to max(σ₁, 1/σ₃)² − 1
    assert vo._isometric_max(np.array([[2.0, 1.1, 0.8]]), p=400)[0] == pytest.approx([3.0], rel=1e-2)
    reflect = np.array([np.diag([1.0, 1.0, -1.0])])
    assert vo.density(reflect, "arap") == pytest.approx([4.0])  # signed σ₃ = −1 is penalised
    for energy in BARRIERS:
        assert vo.density(reflect, energy) == [np.inf]
        assert vo.density(np.array([np.diag([1.0, 1.0, 0.0])]), energy) == [np.inf]


@pytest.mark.parametrize("energy", ENERGIES)
def test_rotations_are_at_the_minimum(energy):
    rng = np.random.default_rng(5)
    R = np.stack([_rotation(q) for q in rng.normal(size=(7, 4))])
    psi, grad, _ = vo.hessian(R, energy)
    assert np.allclose(psi, vo.REST_VALUE[energy], atol=1e-12)
    assert np.allclose(grad, 0, atol=1e-10)


def _ordered_sarap(S):
    """Eq. (11)'s extension written out, on sorted σ (independent of volumetric._sarap)."""
    s1, s2, s3 = np.sort(S, axis=1)[:, ::-1].T
    return (s1 - 1) ** 2 + ((s2 - 1) ** 2 + (1 / s2 - 1) ** 2) / 2 + (1 / s3 - 1) ** 2


def test_sarap_is_the_docstring_formula_and_the_max_over_orderings():
    rng = np.random.default_rng(6)
    S = rng.uniform(0.2, 3.0, size=(2000, 3))
    psi = vo.psi_value("sarap", *S.T)
    assert np.allclose(psi, _ordered_sarap(S), rtol=1e-13)

    def weighted(x):
        return (x[:, 0] - 1) ** 2 + ((x[:, 1] - 1) ** 2 + (1 / x[:, 1] - 1) ** 2) / 2 + (1 / x[:, 2] - 1) ** 2

    best = np.max([weighted(S[:, list(p)]) for p in itertools.permutations(range(3))], axis=0)
    assert np.allclose(psi, best, rtol=1e-13)


@given(A=perturbations, q=rotation_params, q2=rotation_params)
def test_rotation_invariance(A, q, q2):
    J = np.eye(3) + A
    assume(np.linalg.det(J) > 0.05)
    R, R2 = _rotation(q), _rotation(q2)
    for energy in ENERGIES:
        psi = vo.density(np.stack([J, R @ J, J @ R, R @ J @ R2]), energy)
        assert np.allclose(psi, psi[0], rtol=1e-10, atol=1e-12)


@given(A=perturbations)
def test_sarap_treats_a_deformation_and_its_inverse_alike(A):
    J = np.eye(3) + A
    assume(np.linalg.det(J) > 0.05)
    for energy in ("sarap", "isometric", "isometric_max", "isometric_exp"):
        a, b = vo.density(np.stack([J, np.linalg.inv(J)]), energy)
        assert a == pytest.approx(b, rel=1e-9)


@settings(deadline=None)
@given(A=perturbations, q=rotation_params)
def test_sarap_matches_arap_to_second_order_at_rest(A, q):
    """ψ_S-ARAP − ψ_ARAP = −½ w(σ₂) − w(σ₃) = O(ε³) on R(I + εA): the ratio over ε³ stays bounded as ε halves."""
    assume(np.linalg.norm(A) > 0.05)
    R = _rotation(q)
    diffs = []
    for eps in (0.02, 0.01, 0.005):
        J = np.array([R @ (np.eye(3) + eps * A)])
        diffs.append(abs(vo.density(J, "sarap")[0] - vo.density(J, "arap")[0]) / eps**3)
        assert vo.density(J, "arap")[0] > 0
    assert diffs[2] <= 1.2 * diffs[0] + 1e-6 and diffs[2] < 20 * np.linalg.norm(A) ** 3
    _, g_s, H_s = vo.hessian(R[None], "sarap", project=False)
    _, g_a, H_a = vo.hessian(R[None], "arap", project=False)
    assert np.allclose(g_s, g_a, atol=1e-12) and np.allclose(H_s, H_a, atol=1e-9)


def _w(x):
    return (x - 1) ** 2 - (1 / x - 1) ** 2


@given(J2=hnp.arrays(float, (2, 2), elements=st.floats(-0.6, 0.6, allow_nan=False)))
def test_planar_deformations_embedded_in_3d(J2):
    """On J = diag(J₂, 1): ARAP and isometric_exp equal 2D; isometric is 2D + 2; S-ARAP equals Eq. (11) iff
    Σ ≥ 1 ≥ σ and is ½|w| above it otherwise (w(x) = (x − 1)² − (1/x − 1)², the docstring's claim)."""
    J2 = np.eye(2) + J2
    assume(np.linalg.det(J2) > 0.1)
    J3 = np.eye(3)
    J3[:2, :2] = J2
    Sig, sig = planar.signed_svd(J2[None])[1][0]
    for energy, offset in (("arap", 0.0), ("isometric_exp", 0.0), ("isometric", 2.0)):
        assert vo.density(J3[None], energy)[0] == pytest.approx(en.density(J2[None], energy)[0] + offset, rel=1e-10)
    d3, d2 = vo.density(J3[None], "sarap")[0], en.density(J2[None], "sarap")[0]
    extra = 0.0 if Sig >= 1 >= sig else (_w(sig) / 2 if sig > 1 else -_w(Sig) / 2)
    assert d3 - d2 == pytest.approx(extra, rel=1e-8, abs=1e-12)
    assert d3 >= d2 - 1e-12


@pytest.mark.parametrize("mu", [1e-2, 1e-4])
def test_smoothed_sarap_is_within_three_halves_mu(mu):
    """ψ − 3μ/2 ≤ ψ_μ ≤ ψ: one √(b² + μ²) − μ per pair of singular values (2D has one pair: within μ)."""
    S = vo.signed_svd(_random_jacobians(7, n=2000, spread=0.3))[1]
    smooth, exact = vo.psi_value("sarap", *S.T, mu=mu, both=True)
    assert np.array_equal(exact, vo.psi_value("sarap", *S.T))
    gap = exact - smooth
    assert gap.min() >= -1e-15 and gap.max() <= 1.5 * mu + 1e-15
    assert gap.max() > 0.5 * mu  # the bound is used, not loose by orders


# ---------------------------------------------------------------------------------------------- derivatives
@pytest.mark.parametrize(
    "energy,mu",
    [("arap", 0), ("sarap", 0), ("sarap", 1e-3), ("isometric", 0), ("isometric_max", 0), ("isometric_exp", 0)],
)
@settings(deadline=None, max_examples=10)
@given(seed=st.integers(0, 2**16))
def test_gradient_and_exact_hessian_match_finite_differences(energy, mu, seed):
    J = _random_jacobians(seed, n=40)
    assume(len(J) > 5)
    psi, g, H = vo.hessian(J, energy, project=False, mu=mu)
    scale = 1 + np.abs(H).max()
    h = 1e-6
    for k in range(9):
        dJ = h * _unit(k)
        fd_g = (vo.density(J + dJ, energy, mu) - vo.density(J - dJ, energy, mu)) / (2 * h)
        assert np.allclose(fd_g, g.reshape(-1, 9)[:, k], rtol=1e-6, atol=1e-6 * scale)
        fd_h = (vo.gradient(J + dJ, energy, mu)[1] - vo.gradient(J - dJ, energy, mu)[1]).reshape(-1, 9) / (2 * h)
        assert np.allclose(fd_h, H[:, :, k], rtol=1e-5, atol=1e-5 * scale)


@pytest.mark.parametrize("energy", ENERGIES)
def test_projected_hessian_is_psd_and_exact_where_convex(energy):
    rng = np.random.default_rng(8)
    J = np.eye(3) + 0.7 * rng.normal(size=(800, 3, 3))
    if en.is_barrier(energy):
        J = J[np.linalg.det(J) > 0.05]
    J = J[_away_from_kinks(J, min_det=-np.inf, min_gap=1e-3)]
    _, _, H = vo.hessian(J, energy, project=True)
    assert np.allclose(H, np.swapaxes(H, 1, 2))
    assert np.linalg.eigvalsh(H).min() >= -1e-9 * np.abs(H).max()
    _, _, Hx = vo.hessian(J, energy, project=False)
    lo = np.linalg.eigvalsh(Hx).min(axis=1)
    ok = lo > 1e-9
    assert ok.sum() > 10 and np.allclose(H[ok], Hx[ok], atol=1e-9 * np.abs(Hx).max())
    if energy in ("arap", "sarap"):  # these have indefinite exact Hessians: the projection clamped something
        assert (lo < -1e-6).sum() > 10 and not np.allclose(H[~ok], Hx[~ok])


def test_eigensystem_is_orthonormal_and_diagonalises_the_hessian():
    J = _random_jacobians(9, n=100)
    for energy in ("arap", "sarap", "isometric"):
        _, grad, lam, modes = vo.eigensystem(J, energy, project=False)
        assert np.allclose(np.swapaxes(modes, 1, 2) @ modes, np.eye(9), atol=1e-12)
        _, g, H = vo.hessian(J, energy, project=False)
        assert np.allclose(grad, g.reshape(-1, 9))
        assert np.allclose(np.einsum("mik,mij,mjk->mk", modes, H, modes), lam, atol=1e-9 * np.abs(lam).max())


# ---------------------------------------------------------------------------------------------- kinks
def _pair_direction(U, V, pair, theta):
    """Unit anti-conformal direction of a pair: cos θ U(Eᵢᵢ − Eⱼⱼ)Vᵀ/√2 + sin θ U(Eᵢⱼ + Eⱼᵢ)Vᵀ/√2."""
    i, j = pair
    A = np.zeros((3, 3))
    A[i, i], A[j, j] = np.cos(theta) / np.sqrt(2), -np.cos(theta) / np.sqrt(2)
    A[i, j] = A[j, i] = np.sin(theta) / np.sqrt(2)
    return U @ A @ V.T


@pytest.mark.parametrize("kink", [0, 1])
@settings(deadline=None)
@given(s=st.floats(0.4, 2.5), other=st.floats(0.3, 0.9), theta=st.floats(0, 2 * np.pi), q=rotation_params)
def test_kink_radius_is_the_one_sided_slope_and_curvature(kink, s, other, theta, q):
    """On σᵢ = σⱼ = s, ψ along a unit anti-conformal direction of the pair grows like r·t + κ·t²/2."""
    assume(abs(s - 1) > 0.05)
    third = s * other if kink == 0 else s / other  # σ₃ below (σ₁ = σ₂) or σ₁ above (σ₂ = σ₃)
    S = np.array([s, s, third]) if kink == 0 else np.array([third, s, s])
    U, V = _rotation(q), _rotation(q[::-1])
    J0 = U @ np.diag(S) @ V.T
    Z = _pair_direction(U, V, vo.KINK_PAIRS[kink], theta)
    r, kappa = vo.kink_radius(S[None])
    h = 1e-5
    psi = vo.density(np.stack([J0 + t * Z for t in (0.0, h, 2 * h)]), "sarap")
    slope = (-3 * psi[0] + 4 * psi[1] - psi[2]) / (2 * h)
    # the curvature by Richardson's extrapolation of one-sided second differences at steps H and 2H: with H = 1e-5
    # alone, round-off in ψ (up to 30 here) over H² made it wander by 1e-3 relative
    H = 1e-4
    far = vo.density(np.stack([J0 + t * Z for t in (0.0, H, 2 * H, 4 * H)]), "sarap")
    c1, c2 = (far[0] - 2 * far[1] + far[2]) / H**2, (far[0] - 2 * far[2] + far[3]) / (2 * H) ** 2
    curv = 2 * c1 - c2
    assert slope == pytest.approx(r[0, kink], rel=1e-6, abs=1e-8)
    assert curv == pytest.approx(kappa[0, kink], rel=1e-3)
    assert r[0, kink] > 0 and kappa[0, kink] >= (47 / 32, 13 / 32)[kink]
    # the other side of the kink has the same slope: ψ is a cone, and −Z is the opposite ray
    back = vo.density(np.stack([J0 - t * Z for t in (h, 2 * h)]), "sarap")
    assert (-3 * psi[0] + 4 * back[0] - back[1]) / (2 * h) == pytest.approx(r[0, kink], rel=1e-6, abs=1e-8)


def test_on_kink_and_the_held_eigensystem():
    U, V = _rotation(np.array([1.0, 0.2, -0.3, 0.5])), _rotation(np.array([0.3, 1.0, 0.1, -0.2]))
    S = np.array([[1.6, 1.6, 0.9], [1.6, 0.7, 0.7], [1.6, 1.6, 1.6], [1.6, 1.2, 0.7], [1.6, 1.6 - 1e-5, 0.9]])
    J = U @ (S[:, :, None] * np.eye(3)) @ V.T
    on = vo.on_kink(vo.signed_svd(J)[1], 1e-4)
    assert on.tolist() == [[True, False], [False, True], [True, True], [False, False], [True, False]]
    Sj = vo.signed_svd(J)[1]
    assert np.array_equal(vo.on_kink(Sj, np.full(len(S), 1e-4)), on)  # one threshold per tetrahedron
    per_set = np.array([[1e-4, -1.0]] * len(S))  # released from σ₂ = σ₃ (the solver's active set), per set
    assert vo.on_kink(Sj, per_set).tolist() == [[True, False], [False, False], [True, False], [False, False]] + [
        [True, False]
    ]
    near_rest = np.array([[1.001 + 5e-6, 1.001 - 5e-6, 0.9], [1.001, 1.001, 0.9]])  # r ≈ 2e-6: the cone vanishes
    assert vo.on_kink(near_rest, 1e-4)[:, 0].tolist() == [False, True]  # a gap of 1e-5 is off it, 0 is on it
    psi, grad, lam, modes = vo.eigensystem(J, "sarap", project=False, kink=1e-4)
    stiff = vo.kink_stiff_modes(on)
    assert stiff.sum(axis=1).tolist() == [2, 2, 5, 0, 2]
    assert np.allclose(np.swapaxes(modes, 1, 2) @ modes, np.eye(9), atol=1e-12)
    assert np.all(lam[stiff] > 1e7) and np.all(lam[~stiff] < 1e3)
    # the gradient has no component on the stiff modes: the subgradient symmetric in the held pair(s)
    assert np.allclose(np.einsum("mi,mik->mk", grad, modes)[stiff], 0, atol=1e-12)
    free = vo.eigensystem(J, "sarap", project=False)
    assert np.allclose(grad[3], free[1][3]) and np.allclose(lam[3], free[2][3])  # not held: unchanged
    # held on σ₁ = σ₂: ∂ψ/∂σ₁ = ∂ψ/∂σ₂ = the mean of the two one-sided values
    d1 = vo.psi_derivatives("sarap", *S[0])[1][0]
    G = U.T @ grad[0].reshape(3, 3) @ V
    assert np.allclose(np.diag(G), [(d1[0] + d1[1]) / 2] * 2 + [d1[2]], atol=1e-12)


# ---------------------------------------------------------------------------------------------- flip-free step
def test_max_flip_free_step_special_cases():
    I = np.eye(3)[None]
    cases = [
        (np.diag([-2.0, 0, 0]), 0.5),  # linear: 1 − 2t
        (np.diag([-2.0, -2.0, 0]), 0.5),  # double root (1 − 2t)²
        (-2 * np.eye(3), 0.5),  # triple root (1 − 2t)³
        (np.diag([-4.0, -2.0, 0]), 0.25),  # two roots: the smaller
        (np.diag([-1.0, -1.0, -1.0]) * 0.5, 1.0),  # root at t = 2, beyond the cap
        (np.eye(3), 1.0),  # growing: never flips
        (np.zeros((3, 3)), 1.0),  # constant
        (np.array([[0, 1.0, 0], [-1, 0, 0], [0, 0, 0]]), 1.0),  # det(I + t dJ) = 1 + t² > 0 for all t
    ]
    for dJ, t in cases:
        assert vo.max_flip_free_step(I, dJ[None], safety=1.0) == pytest.approx(t, rel=1e-5)
        assert vo.max_flip_free_step(I, dJ[None], safety=1.0) <= t * (1 + 1e-12)  # never past the root
    assert vo.max_flip_free_step(I, np.diag([-2.0, 0, 0])[None], safety=0.9) == pytest.approx(0.45)


@settings(deadline=None, max_examples=30)
@given(seed=st.integers(0, 2**16), spread=st.floats(0.05, 3.0))
def test_max_flip_free_step_is_the_first_root(seed, spread):
    rng = np.random.default_rng(seed)
    J = np.eye(3) + 0.3 * rng.normal(size=(50, 3, 3))
    J = J[np.linalg.det(J) > 0.01]
    dJ = spread * rng.normal(size=J.shape)
    t = vo.max_flip_free_step(J, dJ, safety=1.0)
    ts = np.linspace(0, t * (1 - 1e-7), 400)
    assert all(np.linalg.det(J + s * dJ).min() > 0 for s in ts)
    if t < 1:
        dets = np.linalg.det(J + t * dJ)
        assert np.abs(dets).min() < 1e-8 * np.abs(np.linalg.det(J + 0.5 * t * dJ)).max()  # a root
        assert np.linalg.det(J + t * 1.001 * dJ).min() < 0 or np.abs(dets).min() < 1e-12  # and it is crossed


# ---------------------------------------------------------------------------------------------- references
def test_libigl_element_arap_energy_is_ours():
    """libigl's ARAP_ENERGY_TYPE_ELEMENTS on tets: Σ_edges c_e ‖(x_i − x_j) − R(v_i − v_j)‖² = vol ‖J − R‖²_F."""
    V, T = r3.grid_tets(2)
    X = V + 0.2 * np.random.default_rng(10).normal(size=V.shape)
    ours = r3.volumes(V, T) * vo.density(r3.jacobians(V, T, X), "arap")
    assert np.allclose(r3.libigl_element_arap_energy(V, T, X), ours, rtol=1e-12)


@settings(deadline=None, max_examples=3)
@given(seed=st.integers(0, 2**16))
def test_fd_newton_arap_agrees_with_libigl(seed):
    """The finite-difference Newton reference and libigl's element ARAP (2000 iterations) find the same minimiser,
    with the handles in any order. libigl fits its 3D rotations in single precision (``fit_rotations(S, true, R)``
    in arap_solve), so its fixed point is only ~1e-5 from the double-precision one (measured 8.0e-6)."""
    V, T, handles, targets = r3.twisted_cube(seed)
    X, info = r3.fd_newton(V, T, handles, targets, "arap")
    assert info["grad_norm"] < 1e-7 and np.allclose(X[handles], targets)
    Xi = r3.libigl_arap(V, T, handles, targets, iterations=2000)
    assert np.abs(X - Xi).max() < 5e-5 * (1 + np.abs(targets - V[handles]).max())
    E, Ei = r3.total_energy(V, T, X, "arap"), r3.total_energy(V, T, Xi, "arap")
    assert E <= Ei + 1e-12 and Ei - E < 1e-8 * E
    order = np.argsort(handles)  # the same handles sorted: the same minimiser
    Xs = r3.libigl_arap(V, T, handles[order], targets[order], iterations=2000)
    assert np.abs(Xs - Xi).max() < 1e-9


def test_fd_newton_sarap_is_a_stationary_point_of_the_analytic_gradient():
    """S-ARAP by μ-continuation of the reference Newton; the assembled analytic gradient vanishes there."""
    V, T, handles, targets = r3.twisted_cube(11)
    X = None
    for mu in (1e-2, 1e-4, 0.0):
        X, info = r3.fd_newton(V, T, handles, targets, "sarap", X0=X, mu=mu)
    assert info["grad_norm"] < 1e-7 and np.isfinite(info["energy"])
    _, P = vo.gradient(r3.jacobians(V, T, X), "sarap")
    Gl = np.einsum("m,mab,mcb->mac", r3.volumes(V, T), P, np.linalg.inv(r3._edges(V, T)))  # ∂E/∂(edge c)
    G = np.zeros_like(X)
    for c in range(3):
        np.add.at(G, T[:, c + 1], Gl[:, :, c])
        np.add.at(G, T[:, 0], -Gl[:, :, c])
    G[handles] = 0
    assert np.abs(G).max() < 1e-6


@pytest.mark.parametrize("energy,mu", [("arap", 0), ("sarap", 1e-2), ("isometric", 0), ("isometric_exp", 0)])
def test_exact_hessian_at_repeated_singular_values(energy, mu):
    """Where σᵢ = σⱼ the flip eigenvalue is its limit ψᵢᵢ − ψᵢⱼ (smooth energies): still the exact Hessian."""
    U, V = _rotation(np.array([0.7, -0.2, 0.4, 0.1])), _rotation(np.array([0.1, 0.5, -0.6, 0.3]))
    S = np.array([[1.3, 1.3, 0.8], [1.3, 0.8, 0.8], [0.9, 0.9, 0.9], [1.2, 1.2 - 1e-9, 0.7]])
    J = U @ (S[:, :, None] * np.eye(3)) @ V.T
    _, _, H = vo.hessian(J, energy, project=False, mu=mu)
    h = 1e-6
    for k in range(9):
        dJ = h * _unit(k)
        fd_h = (vo.gradient(J + dJ, energy, mu)[1] - vo.gradient(J - dJ, energy, mu)[1]).reshape(-1, 9) / (2 * h)
        assert np.allclose(fd_h, H[:, :, k], rtol=1e-5, atol=1e-5)


@given(F=hnp.arrays(float, (9,), elements=st.floats(-1, 1, allow_nan=False)), s=st.floats(0.5, 2.0), q=rotation_params)
@settings(deadline=None, max_examples=30)
def test_kink_force_is_the_dual_norm_of_the_cone_at_the_triple_point(F, s, q):
    """On σ₁ = σ₂ = σ₃ = s, ψ grows along the held modes a like vol·(F·a) allows exactly when kink_force ≤ r:
    sup_a F·a / ψ'(a) = kink_force / r, with ψ'(a) the one-sided slope of ψ (finite differences of density)."""
    assume(abs(s - 1) > 0.1 and np.abs(F[[1, 2, 6, 7, 8]]).max() > 0.05)
    U, V = _rotation(q), _rotation(q[::-1])
    J0 = s * U @ V.T
    _, _, _, modes = vo.eigensystem(J0[None], "sarap", project=False, kink=1e-4)
    on = vo.on_kink(np.array([[s, s, s]]), 1e-4)
    assert on.all()
    stiff = vo.kink_stiff_modes(on)[0]
    r = vo.kink_radius(np.array([[s, s, s]]))[0][0, 0]
    ratio = vo.kink_force(on, F[None])[0] / r
    h = 1e-6

    def slope(a):
        Z = (modes[0] @ a).reshape(3, 3)
        return (
            vo.density(np.stack([J0 + h * Z, J0 + 2 * h * Z]), "sarap") @ [4, -1] - 3 * vo.density(J0[None], "sarap")[0]
        ) / (2 * h)

    rng = np.random.default_rng(0)
    for a in rng.normal(size=(200, 9)) * stiff:
        assert F @ a <= ratio * slope(a) * (1 + 1e-5) + 1e-9
    # the maximiser: the projection on G's positive eigenvectors, written in the held modes
    G = np.zeros((3, 3))
    G[np.diag_indices(3)] = vo._HOLD_BASES[2][:, 1:3] @ F[1:3]
    for k, (i, j) in enumerate(vo.PAIRS):
        G[i, j] = G[j, i] = F[6 + k] / np.sqrt(2)
    ev, vec = np.linalg.eigh(G)
    P = (vec * (ev > 0)) @ vec.T  # Π₊
    P -= np.trace(P) / 3 * np.eye(3)
    a = np.zeros(9)
    a[1:3] = vo._HOLD_BASES[2][:, 1:3].T @ np.diag(P)
    a[6:] = [np.sqrt(2) * P[i, j] for i, j in vo.PAIRS]
    assert F @ a == pytest.approx(ratio * slope(a), rel=1e-4)
