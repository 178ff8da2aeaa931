"""Implicit "inside-ness" fields in any dimension: positive inside, about a distance near the boundary.

Procedural shapes are unions (maxima) of tapered capsules, chains of capsules and ellipsoids. Planar
outlines contour these fields (:mod:`defop.geometry.planar.outlines`), volumetric meshes keep the cubes
whose centre is inside them (:mod:`defop.geometry.volumetric`). Every field is element-wise arithmetic
(``+ - * /`` and ``sqrt``, correctly rounded), never BLAS or a transcendental function, so it gives the
same bits on every CPU.
"""

from __future__ import annotations

import numpy as np

__all__ = ["capsule", "chain", "ellipsoid", "union", "subtract"]


def _dot(a, b):
    """Row-wise dot product of two (k, d) arrays (or one row), summed in coordinate order: no BLAS."""
    s = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        s = s + a[..., i] * b[..., i]
    return s


def capsule(a, b, ra, rb=None):
    """Tapered capsule from a (radius ra) to b (radius rb): field = radius(t) - distance.

    Parameters
    ----------
    a, b : (d,) array-like
        End points, d = 2 or 3.
    ra, rb : float
        Radii at a and b (rb defaults to ra).

    Returns
    -------
    f : callable, ``f(P (k, d)) -> (k,)``
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    rb = ra if rb is None else rb
    ab = b - a
    dd = _dot(ab, ab)

    def f(P):
        p = P - a
        t = np.clip(_dot(p, ab) / dd, 0, 1)
        e = p - t[:, None] * ab
        return ra + (rb - ra) * t - np.sqrt(_dot(e, e))

    return f


def chain(points, r0, r1):
    """A tapered tube along a polyline (union of capsules), radius r0 → r1 by arc length.

    Parameters
    ----------
    points : (k, d) array-like
    r0, r1 : float

    Returns
    -------
    f : callable, ``f(P (k, d)) -> (k,)``
    """
    pts = np.asarray(points, float)
    d = np.diff(pts, axis=0)
    L = np.concatenate([[0], np.cumsum(np.sqrt(_dot(d, d)))])
    r = r0 + (r1 - r0) * L / L[-1]
    parts = [capsule(pts[i], pts[i + 1], r[i], r[i + 1]) for i in range(len(pts) - 1)]
    return union(*parts)


def ellipsoid(c, radii):
    """Axis-aligned ellipsoid (an ellipse in 2D), scaled to behave like a distance near the boundary.

    Parameters
    ----------
    c : (d,) array-like
        Centre.
    radii : (d,) array-like
        Semi-axes.

    Returns
    -------
    f : callable, ``f(P (k, d)) -> (k,)``
    """
    c, r = np.asarray(c, float), np.asarray(radii, float)

    def f(P):
        u = (P - c) / r
        return r.min() * (1 - np.sqrt(_dot(u, u)))

    return f


def union(*fields):
    """Union of fields (their maximum)."""

    def f(P):
        return np.max([g(P) for g in fields], axis=0)

    return f


def subtract(f, g):
    """Difference of fields: inside f and outside g."""

    def h(P):
        return np.minimum(f(P), -g(P))

    return h
