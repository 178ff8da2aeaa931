"""Spatial bases Φ: hat functions and the reduced, linearly precise eigenbasis (§3.1)."""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop
from defop.operator import spatial


def test_hat_basis_is_the_identity(grid):
    B = spatial.hat_basis(grid)
    assert B.size == grid.n_vertices
    X = np.random.default_rng(0).normal(size=(grid.n_vertices, 2))
    assert np.array_equal(B.coefficients(X), X) and np.allclose(B.evaluate(X), X)


@pytest.mark.parametrize("name", ["bar", "aleph"])
def test_reduced_basis_null_space_is_exactly_affine(name):
    mesh = dop.shapes.load(name).mesh
    Q = spatial.hessian_energy(mesh)
    affine = np.column_stack([np.ones(mesh.n_vertices), mesh.V])
    assert np.abs(Q @ affine).max() <= 1e-12 * np.abs(Q).max()
    B = spatial.reduced_basis(mesh, k=20)
    lam = B.eigenvalues
    assert lam.shape == (20,) and np.all(np.diff(lam) >= 0)
    assert np.all(lam[:3] == 0) and lam[3] > 1.0  # exactly three null functions, then a clear gap
    # the span reproduces x and y (and constants) to round-off
    assert np.abs(B.evaluate(B.coefficients(mesh.V)) - mesh.V).max() < 1e-10
    # M-orthonormal
    M = mesh.mass_matrix
    assert np.allclose(B.U.T @ (M @ B.U), np.eye(20), atol=1e-12)


def test_reduced_basis_functions_are_smooth_in_order():
    """Higher eigenfunctions carry more Hessian energy: the basis is ordered from smooth to detailed."""
    mesh = dop.shapes.load("bar").mesh
    B = spatial.reduced_basis(mesh, k=12)
    Q = spatial.hessian_energy(mesh)
    energy = np.einsum("ik,ik->k", B.U, Q @ B.U)
    assert np.allclose(energy, B.eigenvalues, rtol=1e-6, atol=1e-8)


def test_affine_residual_annihilates_affine_functions_only():
    mesh = dop.shapes.load("dino", n_vertices=400).mesh
    R = spatial.affine_residual_operator(mesh)
    A = np.column_stack([np.ones(mesh.n_vertices), mesh.V])
    assert np.abs(R @ A).max() < 1e-10
    assert np.abs(R @ mesh.V[:, 0] ** 2).max() > 1e-4


@pytest.mark.parametrize("k", [2, 10_000, 5.5, "n-3", "n-2", "n-1"])
def test_bad_k(k):
    mesh = dop.shapes.load("bar", n_vertices=60).mesh
    k = mesh.n_vertices - int(k[2:]) if isinstance(k, str) else k
    with pytest.raises(ValueError, match="k must be an integer"):
        spatial.reduced_basis(mesh, k)


def test_largest_k_works():
    mesh = dop.shapes.load("bar", n_vertices=60).mesh
    B = spatial.reduced_basis(mesh, mesh.n_vertices - 4)
    assert B.size == mesh.n_vertices - 4  # |Φ| = k: the affine functions are among the k
    assert np.isfinite(B.U).all()


def test_unknown_kind(grid):
    with pytest.raises(ValueError, match="unknown spatial basis 'fourier'"):
        spatial.make_spatial(grid, "fourier")


@pytest.mark.parametrize("lead", [(), (5,), (3, 4), (0,)])
def test_projection_of_a_batch_equals_the_projection_of_each(lead):
    """The L² projection of (..., n_vertices, d) data, one matrix product, equals each configuration's own
    U^T M X (any leading dimensions, an empty batch included)."""
    mesh = dop.shapes.load("bar", n_vertices=200).mesh
    phi = spatial.make_spatial(mesh, "reduced", 12)
    X = np.random.default_rng(1).standard_normal((*lead, mesh.n_vertices, 2))
    A = phi.coefficients(X)
    assert A.shape == (*lead, 12, 2)
    M = mesh.mass_matrix.diagonal()[:, None]
    for i in np.ndindex(*lead):
        np.testing.assert_allclose(A[i], phi.U.T @ (M * X[i]), rtol=0, atol=1e-13)
