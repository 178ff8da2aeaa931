"""Handle bases Ψ: sizes, linear reproduction, TPS side conditions, bad input."""

from __future__ import annotations

from math import comb

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from defop.operator import handle_bases as hb

P = np.array([[0.0, 0.0], [1.0, 0.5], [0.3, 1.2]])


@pytest.mark.parametrize("n", [1, 2, 5])
def test_sizes(n):
    Pn = np.random.default_rng(0).normal(size=(n, 2))
    C = Pn + np.random.default_rng(1).normal(size=(7, n, 2))
    assert hb.make_basis("linear", Pn).size == 2 * n + 1
    assert hb.make_basis("quadratic", Pn).size == 1 + 3 * n + 2 * n * n
    assert hb.make_basis("cubic", Pn).size == comb(2 * n + 3, 3)
    assert hb.make_basis("tps", Pn, C).size == 1 + 2 * n + 7
    for kind in hb.KINDS:
        b = hb.make_basis(kind, Pn, C)
        assert b.size == hb.basis_size(kind, n, 7)
        assert b(Pn + 0.1).shape == (b.size,) and b(C).shape == (7, b.size)


def test_first_functions_are_one_and_the_displacements():
    Q = P + [[0.1, -0.2], [0.0, 0.3], [0.5, 0.5]]
    for kind in hb.KINDS:
        b = hb.make_basis(kind, P, P[None] + np.random.default_rng(2).normal(size=(6, 3, 2)), scale=2.0)
        psi = b(Q)
        assert psi[0] == 1.0 and np.allclose(psi[1:7], (Q - P).ravel() / 2.0)
        for j in range(3):
            for c in range(2):
                assert b.linear_coefficients(j, c) @ psi == pytest.approx(Q[j, c])


def test_monomials_are_products():
    b = hb.make_basis("cubic", P[:1])  # z in R^2: 1, z1, z2, z1², z1z2, z2², z1³, z1²z2, z1z2², z2³
    z = np.array([0.5, -2.0])
    expect = [
        1,
        z[0],
        z[1],
        z[0] ** 2,
        z[0] * z[1],
        z[1] ** 2,
        z[0] ** 3,
        z[0] ** 2 * z[1],
        z[0] * z[1] ** 2,
        z[1] ** 3,
    ]
    assert np.allclose(b(P[:1] + z), expect)


def test_tps_kernel_and_side_conditions():
    C = P[None] + np.random.default_rng(3).normal(size=(5, 3, 2))
    b = hb.TPSBasis(P, C)
    psi = b(C[2])
    r = np.linalg.norm((C[2] - C).reshape(5, -1), axis=1)
    assert np.allclose(psi[7:], hb.tps_kernel(r)) and psi[7 + 2] == 0.0
    T = b.side_conditions()
    assert T.shape == (7, b.size) and np.all(T[:, :7] == 0)
    # weights w with T w = 0: sum to zero and orthogonal to the centres' linear part
    assert np.allclose(T[0, 7:], 1) and np.allclose(T[1:, 7:].T, b.z(C))


def test_bad_input():
    with pytest.raises(ValueError, match="duplicate TPS centres 0 and 2"):
        hb.TPSBasis(P, np.stack([P + 1, P + 2, P + 1]))
    b = hb.make_basis("quadratic", P)
    with pytest.raises(ValueError, match=r"Q must have shape \(3, 2\) or \(k, 3, 2\)"):
        b(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        b(np.full((3, 2), np.nan))
    with pytest.raises(ValueError, match="unknown handle basis 'rbf'"):
        hb.make_basis("rbf", P)
    with pytest.raises(ValueError, match="needs centers"):
        hb.make_basis("tps", P)


@pytest.mark.parametrize("kind", ["linear", "quadratic", "cubic", "tps"])
def test_evaluate_one_fast_path_matches_call(kind):
    rng = np.random.default_rng(3)
    P = rng.standard_normal((4, 2))
    C = P + 0.3 * rng.standard_normal((30, 4, 2))
    b = hb.make_basis(kind, P, centers=C if kind == "tps" else None, scale=0.7)
    for Q in (C[5], P + 0.1, P):  # a centre (r = 0), a generic point, the rest pose
        assert np.allclose(b.evaluate_one(b.z(Q)), b(Q), rtol=0, atol=1e-12)


#: a basis kind, 1-3 moving handles, a seed and how far Q goes from P (the δψ properties below)
_RANDOM_DELTA_CASES = given(
    kind=st.sampled_from(["linear", "quadratic", "cubic", "tps"]),
    n=st.integers(1, 3),
    seed=st.integers(0, 2**31 - 1),
    far=st.sampled_from([1e-3, 1.0, 1e3]),
)


def _random_basis(kind, n, seed):
    """(rng, P (n,2), Ψ) with random rest handles, and 2n + 4 random TPS centres around them for TPS."""
    rng = np.random.default_rng(seed)
    P = rng.standard_normal((n, 2))
    centers = P + rng.standard_normal((2 * n + 4, n, 2)) if kind == "tps" else None
    return rng, P, hb.make_basis(kind, P, centers=centers, scale=0.7)


@settings(max_examples=25, deadline=None)
@_RANDOM_DELTA_CASES
def test_delta_is_psi_relative_to_rest_and_exactly_zero_there(kind, n, seed, far):
    # DefOp's (★) needs δψ(P) = 0 bit for bit on the batch and the single-frame paths
    rng, P, psi = _random_basis(kind, n, seed)
    zero = psi.z(P)
    assert np.all(psi.delta_z(zero[None]) == 0) and np.all(psi.delta_one(zero) == 0)
    Q = P + far * rng.standard_normal((3, n, 2))
    z = psi.z(Q)
    ref = psi(Q)[:, 1:] - psi(P)[1:]
    scale = np.abs(psi(Q)).max()
    assert np.allclose(psi.delta_z(z), ref, rtol=0, atol=1e-12 * scale)
    assert np.allclose(np.array([psi.delta_one(zi) for zi in z]), ref, rtol=0, atol=1e-12 * scale)


def test_non_finite_Q_is_named():
    psi = hb.make_basis("linear", np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"Q has NaN or infinite entries \(first at \[1, 0\]\)"):
        psi(np.array([[0.0, 0.0], [np.inf, 0.0]]))


@settings(max_examples=25, deadline=None)
@_RANDOM_DELTA_CASES
def test_delta_raw_times_raw_scale_is_delta_and_bounded(kind, n, seed, far):
    # the fast paths of DefOp multiply delta_raw by matrices with raw_scale folded in: the product must be δψ,
    # exactly 0 at rest (single row and batch), and raw_bound(R) must bound it for |Q − P| ≤ R (overflow guard)
    rng, P, psi = _random_basis(kind, n, seed)
    q = psi.size - 1
    zero = np.zeros(2 * n)
    assert np.all(psi.delta_raw(zero, 0.0, np.empty(q, np.float32)) == 0)
    assert np.all(psi.delta_raw(zero[None].repeat(3, 0), np.zeros(3), np.empty((3, q))) == 0)
    dz = far * rng.standard_normal((4, 2 * n))
    zz = np.sum(dz**2, axis=1)
    batch = psi.delta_raw(dz, zz, np.empty((4, q)))
    single = np.array([psi.delta_raw(r, float(r @ r), np.empty(q)) for r in dz])
    ref = psi.delta_z(dz / psi.scale)
    scale = np.abs(psi(P + dz.reshape(4, n, 2))).max()
    assert np.allclose(batch * psi.raw_scale, ref, rtol=0, atol=1e-10 * scale)
    assert np.allclose(single * psi.raw_scale, ref, rtol=0, atol=1e-10 * scale)
    R = float(np.sqrt(zz.max()))
    assert np.abs(batch).max() <= psi.raw_bound(R)
