"""Distinct verified minima: the candidates at one sample, lowest energy first, one per minimum.

Two configurations are one minimum when their distance is at most ``tol`` × the mesh's bounding-box diagonal. The
distance is a choice of the caller: ``"max"``, the largest coordinate difference over the vertices (the multilevel
policy's coarse candidates), or ``"rms"``, the mass-weighted RMS length of the difference (branch grouping,
:func:`rms`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["METRICS", "distinct_minima", "rms"]

#: the distances :func:`distinct_minima` knows
METRICS = ("max", "rms")


def rms(mesh, D):
    """M-weighted RMS length of displacement fields D (..., n_vertices, d): sqrt(Σ_v m_v |D_v|² / Σ_v m_v)."""
    w = mesh.mass_matrix.diagonal()
    return np.sqrt(np.einsum("v,...vc->...", w, D**2) / w.sum())


def distinct_minima(X, energy, converged, tol, diagonal, metric="max", mesh=None):
    """Indices of the distinct verified candidates, lowest energy first (a stable sort: ties keep their order).

    A verified candidate is kept when it is farther than ``tol`` × ``diagonal`` from every candidate kept before.

    Parameters
    ----------
    X : (c, n_vertices, d) array or sequence of (n_vertices, d) arrays
        The candidates.
    energy : (c,) array
        Their energies (only the verified ones are compared).
    converged : (c,) bool array
        Verified local minima; the others are left out.
    tol : float
        Relative distance below which two minima are one.
    diagonal : float
        The mesh's bounding-box diagonal.
    metric : {"max", "rms"}
        The distance: largest coordinate difference, or the M-weighted RMS length (:func:`rms`, needs ``mesh``).
    mesh : defop.geometry.mesh.Mesh, optional
        For ``metric="rms"``.

    Returns
    -------
    kept : list of int
    """
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if metric == "rms" and mesh is None:
        raise ValueError("metric='rms' needs the mesh (its mass matrix weighs the vertices)")
    ok = np.flatnonzero(np.asarray(converged, dtype=bool))
    E = np.asarray(energy, dtype=float)
    kept = []
    for c in ok[np.argsort(E[ok], kind="stable")]:
        if all(_distance(X[c] - X[j], metric, mesh) > tol * diagonal for j in kept):
            kept.append(int(c))
    return kept


def _distance(D, metric, mesh):
    return np.abs(D).max() if metric == "max" else rms(mesh, D)
