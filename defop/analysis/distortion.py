"""How a deformation distorts the shape, above all at its handles: the cusps, folds and scaling of Fig. 6.

* :func:`corner_angles` and :func:`one_rings`: per-corner angles and the triangles around given vertices;
* :func:`handle_distortion`: per handle, the largest corner-angle change, the largest Σ/σ and the flips in its
  one-ring (ARAP's cusps);
* :func:`deformation_summary`: what Fig. 6 compares between energies (flips, cusps, area change, scaling).

No plotting here (:func:`defop.view.plot.plot_handle_zoom` draws the one-ring measure).
"""

from __future__ import annotations

import numpy as np

from ..geometry.mesh import signed_areas
from ..variational.planar import svd_frame
from ..variational.problem import check_handles

__all__ = ["corner_angles", "one_rings", "handle_distortion", "deformation_summary"]


def corner_angles(V, F):
    """Signed interior angle at each corner of each triangle, in radians.

    Parameters
    ----------
    V : (n,2) numpy array
    F : (m,3) int numpy array

    Returns
    -------
    angles : (m,3) numpy array
        ``angles[t, k]`` at vertex ``F[t, k]``; all three are negative on a triangle that is flipped
        (negatively oriented), so a fold shows as an angle change of more than the rest angle.
    """
    P = np.asarray(V, float)[np.asarray(F)]
    a, b = np.roll(P, -1, axis=1) - P, np.roll(P, 1, axis=1) - P  # the two edges leaving each corner
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return np.arctan2(cross, np.sum(a * b, axis=-1))


def one_rings(F, vertices):
    """Triangles incident to each vertex.

    Parameters
    ----------
    F : (m,3) int numpy array
    vertices : (h,) int numpy array

    Returns
    -------
    rings : list of h int numpy arrays
        Triangle indices around each vertex.
    """
    F = np.asarray(F)
    return [np.flatnonzero((F == v).any(axis=1)) for v in np.asarray(vertices, int)]


def handle_distortion(mesh, X, vertices):
    """Distortion in the one-ring of each handle: how sharp a cusp the deformation X makes there (Fig. 6).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array
        Deformed vertex positions.
    vertices : (h,) int numpy array
        Handle vertices (or an (n,) boolean mask, as :func:`defop.variational.problem.check_handles` accepts).

    Returns
    -------
    distortion : dict of (h,) numpy arrays
        ``angle``: the largest change of a corner angle (degrees) over the one-ring, signed angles (a flipped
        triangle changes each angle by more than its rest value); ``conformal``: the largest Σ/σ (+inf on a
        flipped or collapsed triangle); ``flipped``: flipped or collapsed triangles in the one-ring.

    Raises
    ------
    ValueError
        X of the wrong shape or not finite; handle vertices empty, non-integer or out of range.
    """

    X = np.asarray(X, float)
    if X.shape != mesh.V.shape:
        raise ValueError(f"X must have shape {mesh.V.shape}, got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError(f"X has NaN or infinite entries (vertex {int(np.flatnonzero(~np.isfinite(X).all(1))[0])})")
    vertices = check_handles(mesh, vertices)
    change = np.degrees(np.abs(corner_angles(X, mesh.F) - corner_angles(mesh.V, mesh.F))).max(axis=1)

    S = svd_frame(mesh.jacobians(X))[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(S[:, 1] > 0, S[:, 0] / S[:, 1], np.inf)
    folded = S[:, 1] <= 0
    rings = one_rings(mesh.F, vertices)
    return {
        "angle": np.array([change[r].max() for r in rings]),
        "conformal": np.array([K[r].max() for r in rings]),
        "flipped": np.array([int(folded[r].sum()) for r in rings]),
    }


def deformation_summary(mesh, X, vertices, expand=1.1):
    """What Fig. 6 compares between energies: folds, cusps at the handles, and scaling.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n,2) numpy array
    vertices : (h,) int numpy array
        The moving handles.
    expand : float
        A triangle counts as scaled up when both singular values exceed it (grown in every direction).

    Returns
    -------
    summary : dict
        ``flips`` (flipped or collapsed triangles), ``flips_at_handles`` (those in a handle's one-ring),
        ``handle_angle`` (the largest corner-angle change in any handle's one-ring, degrees, see
        :func:`handle_distortion`), ``area_change`` (total signed area / rest area − 1), ``scaled`` (area fraction
        of triangles scaled up by more than ``expand`` in every direction, σ > expand), ``median_conformal``
        (area-weighted median of Σ/|σ| over the mesh: 1 for a map that only rotates and scales).
    """

    d = handle_distortion(mesh, X, vertices)
    S = svd_frame(mesh.jacobians(X))[0]
    A = mesh.areas
    w = A / A.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(S[:, 1] != 0, S[:, 0] / np.abs(S[:, 1]), np.inf)  # a triangle collapsed to a point: inf, not 0/0
    order = np.argsort(K)
    median = float(K[order][np.searchsorted(np.cumsum(w[order]), 0.5)])
    return {
        "flips": int(np.count_nonzero(S[:, 1] <= 0)),
        "flips_at_handles": int(d["flipped"].sum()),
        "handle_angle": float(d["angle"].max()),
        "area_change": float(signed_areas(X, mesh.F).sum() / A.sum() - 1),
        "scaled": float(w @ (S[:, 1] > expand)),
        "median_conformal": median,
    }
