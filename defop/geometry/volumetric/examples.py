"""Example closed triangle surfaces, generated: what a user's surface file holds, for tests and benchmarks."""

from __future__ import annotations

import numpy as np

__all__ = ["torus_surface"]


def torus_surface(nu=48, nv=24, R=1.0, r=0.35):
    """A closed, outward-oriented torus around the z axis through the origin, as a triangle surface.

    Parameters
    ----------
    nu, nv : int
        Vertices around the ring and around the tube (at least 3 each).
    R, r : float
        Ring and tube radii, 0 < r < R.

    Returns
    -------
    V : (nu·nv, 3) numpy array
    F : (2·nu·nv, 3) int numpy array
    """
    if int(nu) != nu or int(nv) != nv or nu < 3 or nv < 3 or not 0 < r < R:
        raise ValueError(f"need integers nu, nv >= 3 and 0 < r < R, got nu={nu!r}, nv={nv!r}, R={R!r}, r={r!r}")
    nu, nv = int(nu), int(nv)
    u, v = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nv) * 2 * np.pi / nv, indexing="ij")
    V = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a, b = i * nv + j, (i + 1) % nu * nv + j
    c, d = (i + 1) % nu * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    F = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return V.reshape(-1, 3), F
