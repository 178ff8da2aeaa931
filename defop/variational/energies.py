"""Deformation energies of the paper as pure, vectorised functions of the Jacobians J (m, d, d).

Each energy is E(X) = Σ_t A_t ψ(J_t), a sum over elements weighted by area (volume in 3D), of an isotropic
function ψ of the *signed* singular values Σ ≥ |σ| of the element's Jacobian (σ < 0 when
det J < 0, so that a fold is seen rather than hidden). In 2D:

* ``"arap"``: ARAP, Eq. (10): ψ = (Σ−1)² + (σ−1)².
* ``"sarap"``: Symmetric ARAP (S-ARAP), Eq. (11): ψ = (Σ−1)² + (1/σ−1)², +inf when det J ≤ 0;
  shrinking and stretching are penalised alike, and the 1/σ term is a barrier against flips.
* ``"isometric"``: the symmetric Dirichlet energy
  ψ = ‖J‖²_F + ‖J⁻¹‖²_F = Σ² + σ² + Σ⁻² + σ⁻², +inf when det J ≤ 0; its minimum 4 is at rotations.
  The isometric energy of later papers by the same group; it treats each singular value on its own
  and does not scale the shape (notebook 01: under Fig. 6's stretch it changes the area like ARAP).
* ``"isometric_max"``: the squared isometric distortion max(Σ, 1/σ)² of Poranne & Lipman (2014,
  "Provably good planar mappings"), smoothed by the p-norm of (Σ, σ, 1/Σ, 1/σ):
  ψ = (Σᵖ + σᵖ + Σ⁻ᵖ + σ⁻ᵖ)^(2/p) − 4^(2/p), p = ``MAX_POWER`` (64); +inf when det J ≤ 0. p = 2 is the
  symmetric Dirichlet energy minus 4; p → ∞ gives max(Σ, 1/σ)² − 1, which does not see σ at all while
  Σ dominates (a stretched triangle may grow in both directions at no cost).
* ``"isometric_exp"``: the exponential symmetric Dirichlet energy ψ = exp(s (‖J‖²_F + ‖J⁻¹‖²_F − 4)) − 1,
  s = ``EXP_SCALE`` (1/4), +inf when det J ≤ 0 (``EXP_SYMMETRIC_DIRICHLET`` of libigl's SLIM,
  Rabinovich et al. 2017): a high-growth isometric energy that penalises the worst triangle most.

This module is the one face of the closed forms: :func:`density`, :func:`gradient`, :func:`eigensystem`
(ψ, ∂ψ/∂J and the analytic eigensystem of the Hessian, PSD-projected), :func:`hessian`, :func:`total_energy`
and :func:`max_flip_free_step` read d from ``J.shape[-1]`` and call the 2×2 closed forms of
:mod:`defop.variational.planar` (d = 2) or the 3×3 ones (d = 3, :func:`closed_forms`: the only place where the
dimension is chosen).
"""

from __future__ import annotations

import numpy as np

from .definitions import BARRIER, ENERGIES, EXP_SCALE, MAX_POWER, REST_VALUE, check_energy, is_barrier

__all__ = [
    "BARRIER",
    "ENERGIES",
    "EXP_SCALE",
    "MAX_POWER",
    "REST_VALUE",
    "check_energy",
    "closed_forms",
    "density",
    "eigensystem",
    "gradient",
    "hessian",
    "is_barrier",
    "max_flip_free_step",
    "total_energy",
]


def closed_forms(J):
    """The module of closed forms for Jacobians J (m, d, d): the one place where 2D and 3D part.

    Parameters
    ----------
    J : (m, d, d) array-like

    Returns
    -------
    module
        :mod:`defop.variational.planar` for d = 2, :mod:`defop.variational.volumetric` for d = 3. Their functions
        (``density``, ``gradient``, ``eigensystem``, ``max_flip_free_step``) take and return arrays of the shapes
        documented here.

    Raises
    ------
    ValueError
        J is not an (m, d, d) stack with d = 2 or 3.
    """
    shape = np.shape(J)
    if len(shape) != 3 or shape[1] != shape[2] or shape[-1] not in (2, 3):
        raise ValueError(f"J must be an (m, d, d) array of Jacobians with d = 2 or 3, got shape {shape}")
    if shape[-1] == 3:
        from . import volumetric

        return volumetric
    from . import planar

    return planar


def density(J, energy, mu=0.0, both=False):
    """ψ(J_t) per element.

    Parameters
    ----------
    J : (m, d, d) numpy array
    energy : str
        One of :data:`ENERGIES`.
    mu : float
        S-ARAP smoothing (:func:`defop.variational.planar.psi_sarap_smooth`).
    both : bool
        Return (ψ_μ, ψ): the smoothed S-ARAP and Eq. (11) itself, from one SVD.

    Returns
    -------
    psi : (m,) numpy array
        +inf on flipped elements for the barrier energies.
    """
    check_energy(energy)
    return closed_forms(J).density(J, energy, mu, both)


def gradient(J, energy, mu=0.0):
    """∂ψ/∂J per element: U diag(∂ψ/∂σ_i) Vᵀ.

    Parameters
    ----------
    J : (m, d, d) numpy array
    energy : str

    Returns
    -------
    psi : (m,) numpy array
    dpsi : (m, d, d) numpy array
        Only meaningful where ψ is finite.
    """
    check_energy(energy)
    return closed_forms(J).gradient(J, energy, mu)


def eigensystem(J, energy, project=True, mu=0.0, kink=0.0):
    """ψ, ∂ψ/∂J and the analytic eigensystem of the Hessian ∂²ψ/∂vec(J)² per element.

    Parameters
    ----------
    J : (m, d, d) numpy array
    energy : str
    project : bool
        Clamp negative eigenvalues to zero (PSD).
    mu : float
        S-ARAP smoothing.
    kink : float or (m,) numpy array
        S-ARAP with ``mu = 0``: elements within ``kink`` of Eq. (11)'s kink sit on it (see
        :func:`defop.variational.planar.eigensystem`).

    Returns
    -------
    psi : (m,) numpy array
    grad : (m, d²) numpy array
        vec(∂ψ/∂J), row-major.
    lam : (m, d²) numpy array
        Eigenvalues; non-finite ones are set to 0.
    modes : (m, d², d²) numpy array
        ``modes[t, :, k]`` is the k-th unit eigenvector, vec of the eigenmatrix.
    """
    check_energy(energy)
    return closed_forms(J).eigensystem(J, energy, project, mu, kink)


def hessian(J, energy, project=True, mu=0.0):
    """ψ, ∂ψ/∂J and the (projected) Hessian ∂²ψ/∂vec(J)² per element.

    Parameters
    ----------
    J : (m, d, d) numpy array
    energy : str
    project : bool
        Clamp negative eigenvalues to zero (PSD); otherwise the exact Hessian (where ψ is smooth).

    Returns
    -------
    psi : (m,) numpy array
    dpsi : (m, d, d) numpy array
    H : (m, d², d²) numpy array
        In row-major vec(J); assembled from :func:`eigensystem`.
    """
    psi, grad, lam, modes = eigensystem(J, energy, project, mu)
    H = np.matmul(modes * lam[:, None, :], np.swapaxes(modes, 1, 2))
    d = np.shape(J)[-1]
    return psi, grad.reshape(-1, d, d), H


def total_energy(mesh, X, energy, mu=0.0):
    """E(X) = Σ_t A_t ψ(J_t) (Eq. 10 / 11), +inf if a barrier energy sees a flipped element.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n, d) numpy array
    energy : str

    Returns
    -------
    E : float
    """
    psi = density(mesh.jacobians(X), energy, mu)
    return float(mesh.areas @ psi)


def max_flip_free_step(J, dJ, safety=0.9):
    """Largest t in (0, 1] such that det(J + s·dJ) > 0 for all s in [0, t) (Smith & Schaefer 2015).

    det(J + t·dJ) is a polynomial of degree d in t (a quadratic in 2D, a cubic in 3D); the step is ``safety``
    times its smallest positive root over all elements, capped at 1.

    Parameters
    ----------
    J, dJ : (m, d, d) numpy arrays
        Current Jacobians (all det > 0) and their change along the search direction.
    safety : float

    Returns
    -------
    t : float
    """
    cf = closed_forms(J)
    if np.shape(J)[-1] == 2 and np.shape(dJ) == np.shape(J):  # one compiled pass, the same formulas
        from . import fused

        J, dJ = np.ascontiguousarray(J, dtype=float), np.ascontiguousarray(dJ, dtype=float)
        return float(fused.flip_free_step2(J, dJ, float(safety)))
    return cf.max_flip_free_step(J, dJ, safety)
