"""Training handle configurations Q_k (§3.3).

Each Q_k is drawn independently per moving handle l, around its rest position p_l, from the handle's
region: uniform in a disc, on a circle, Gaussian, uniform in the Voronoi cell of p_l with respect to the
other moving handles (clipped to a disc), or a mixture of these (Fig. 1 mixes discs and Voronoi cells).
Fixed handles are not variables: they stay at rest and are not part of Q. All randomness goes through
the ``rng`` argument (a ``numpy.random.Generator``).
"""

from __future__ import annotations

import numpy as np

from .shapes import check_region


def _disc(rng, k, radius):
    r = radius * np.sqrt(rng.uniform(size=k))
    t = rng.uniform(0, 2 * np.pi, size=k)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def sample_region(rng, region, center, m, P=None, index=None):
    """m points of one handle's region.

    Parameters
    ----------
    rng : numpy.random.Generator
    region : dict
        See :class:`defop.shapes.Shape`.
    center : (2,) numpy array
        The handle's rest position p_l.
    m : int
    P : (n,2) numpy array, optional
        All moving handles' rest positions (for ``voronoi``).
    index : int, optional
        Row of this handle in ``P``.

    Returns
    -------
    points : (m,2) numpy array
    """
    kind = region["kind"]
    c = np.asarray(center, float)
    if kind == "disc":
        return c + _disc(rng, m, region["radius"])
    if kind == "ellipse":
        return c + _disc(rng, m, 1.0) * np.asarray(region["axes"], float)
    if kind == "circle":
        t = rng.uniform(0, 2 * np.pi, size=m)
        return c + region["radius"] * np.column_stack([np.cos(t), np.sin(t)])
    if kind == "gaussian":
        return c + rng.normal(scale=region["sigma"], size=(m, 2))
    if kind == "voronoi":
        others = np.delete(np.asarray(P, float), index, axis=0) if P is not None else np.zeros((0, 2))
        out = np.empty((0, 2))
        for _ in range(1000):
            cand = c + _disc(rng, max(2 * (m - len(out)), 16), region["radius"])
            if len(others):
                d_own = np.sum((cand - c) ** 2, axis=1)
                d_other = np.min(np.sum((cand[:, None] - others[None]) ** 2, axis=-1), axis=1)
                cand = cand[d_own <= d_other]
            out = np.vstack([out, cand])
            if len(out) >= m:
                return out[:m]
        raise ValueError(f"the Voronoi region of handle {index} is too small to sample")
    if kind == "mixture":
        w = np.asarray(region["weights"], float)
        comp = rng.choice(len(w), size=m, p=w / w.sum())
        out = np.empty((m, 2))
        for j, sub in enumerate(region["components"]):
            sel = np.flatnonzero(comp == j)
            if len(sel):
                out[sel] = sample_region(rng, sub, c, len(sel), P, index)
        return out
    check_region(region)
    raise AssertionError  # pragma: no cover


def sample_handles(P, regions, m, rng):
    """m configurations of the moving handles.

    Parameters
    ----------
    P : (n,2) numpy array
        Rest positions of the moving handles.
    regions : list of dict
        One region per moving handle.
    m : int
        Number of samples.
    rng : numpy.random.Generator or int
        Randomness (an int seeds ``numpy.random.default_rng``).

    Returns
    -------
    Q : (m,n,2) numpy array
    """
    P = np.asarray(P, float)
    if len(regions) != len(P):
        raise ValueError(f"{len(regions)} regions for {len(P)} moving handles")
    if int(m) != m or m < 1:
        raise ValueError(f"m must be a positive integer, got {m!r}")
    for i, r in enumerate(regions):
        check_region(r, f"region {i}")
    rng = np.random.default_rng(rng)
    Q = np.empty((int(m), len(P), 2))
    for i, region in enumerate(regions):
        Q[:, i] = sample_region(rng, region, P[i], int(m), P, i)
    return Q


def sample_shape(shape, m, rng):
    """m configurations of a :class:`defop.shapes.Shape`'s moving handles, from its regions.

    Returns
    -------
    Q : (m,n,2) numpy array
    """
    return sample_handles(shape.P_moving, shape.regions, m, rng)
