"""Training handle configurations Q_k (§3.3).

Each Q_k is drawn independently per moving handle l, around its rest position p_l, from the handle's
region (:mod:`defop.scene.regions`; 2D or 3D, d read from P): uniform in a disc or ball, on a circle,
Gaussian, uniform in the Voronoi cell of p_l with respect to the other moving handles (clipped to a ball),
or a mixture of these (Fig. 1 mixes discs and Voronoi cells).
Fixed handles are not variables: they stay at rest and are not part of Q. All randomness goes through
the ``rng`` argument (a ``numpy.random.Generator``).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from ..scene.regions import as_region


def sample_region(rng, region, center, m, P=None, index=None):
    """m points of one handle's region (see :meth:`defop.scene.regions.Region.sample`).

    Parameters
    ----------
    rng : numpy.random.Generator
    region : defop.scene.regions.Region or dict
    center : (d,) numpy array
        The handle's rest position p_l.
    m : int
    P : (n,d) numpy array, optional
        All moving handles' rest positions (for ``voronoi``).
    index : int, optional
        Row of this handle in ``P``.

    Returns
    -------
    points : (m,d) numpy array
    """
    return as_region(region).sample(rng, center, m, P, index)


def sample_handles(P, regions, m, rng):
    """m configurations of the moving handles.

    Parameters
    ----------
    P : (n,d) numpy array
        Rest positions of the moving handles, d = 2 or 3.
    regions : list of defop.scene.regions.Region or dict
        One region per moving handle.
    m : int
        Number of samples.
    rng : numpy.random.Generator or int
        Randomness (an int >= 0 seeds ``numpy.random.default_rng``; anything else is a ValueError naming ``rng``).

    Returns
    -------
    Q : (m,n,d) numpy array
    """
    P = np.asarray(P, float)
    if P.ndim != 2 or P.shape[1] not in (2, 3):
        raise ValueError(f"P must have shape (n, d) with d = 2 or 3, got {P.shape}")
    if len(regions) != len(P):
        raise ValueError(f"{len(regions)} regions for {len(P)} moving handles")
    if int(m) != m or m < 1:
        raise ValueError(f"m must be a positive integer, got {m!r}")
    regions = [as_region(r, f"region {i}") for i, r in enumerate(regions)]
    rng = opt.rng(rng)
    Q = np.empty((int(m), *P.shape))
    for i, region in enumerate(regions):
        Q[:, i] = region.sample(rng, P[i], int(m), P, i)
    return Q


def sample_shape(shape, m, rng):
    """m configurations of a :class:`defop.scene.shapes.Shape`'s moving handles, from its regions.

    Returns
    -------
    Q : (m,n,d) numpy array
    """
    return sample_handles(shape.P_moving, shape.regions, m, rng)
