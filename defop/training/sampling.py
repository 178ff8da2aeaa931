"""Training handle configurations Q_k (§3.3).

Each Q_k is drawn independently per moving handle l, around its rest position p_l, from the handle's
region (:mod:`defop.scene.regions`; 2D or 3D, d read from P): uniform in a disc or ball, on a circle,
Gaussian, uniform in the Voronoi cell of p_l with respect to the other moving handles (clipped to a ball),
or a mixture of these (Fig. 1 mixes discs and Voronoi cells). A 3D handle patch that moves as one rigid piece
(a beam's end) is sampled by :func:`twist_bend_samples` (rigid motions from :func:`patch_motions`, plus a jitter).
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


def _across(axis):
    """The two coordinate axes other than ``axis`` (0, 1 or 2), in order; ValueError naming axis otherwise."""
    if isinstance(axis, bool) or axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis!r}")
    return [c for c in range(3) if c != axis]


def patch_motions(P, angles, shifts, axis=0):
    """Rigid motions of a 3D handle patch: turned by ``angles`` about the coordinate axis ``axis`` through the
    patch's centroid, then moved by ``shifts``.

    A patch of handles that moves as one rigid piece (the end of a beam, a hand, a foot) is how a 3D model is
    usually posed: this gives its configurations Q_k exactly, e.g. a twist and a bend of a beam's end (Fig. 7 in
    3D). Random samples of such motions for training: :func:`twist_bend_samples`.

    Parameters
    ----------
    P : (h,3) array_like
        Rest positions of the patch's handles.
    angles : (k,) array_like
        Twist angles, radians (right-hand rule about +axis).
    shifts : (k,3) array_like
        Translations of the patch.
    axis : int
        0, 1 or 2: the beam's axis.

    Returns
    -------
    Q : (k,h,3) numpy array
        One configuration per angle (``train(..., samples=Q)``), k = 0 giving an empty (0,h,3) array.

    Raises
    ------
    ValueError
        P not (h,3), angles and shifts not finite or of different lengths, or axis not 0, 1 or 2.
    """
    P = np.asarray(P, float)
    a = np.atleast_1d(np.asarray(angles, float))
    t = np.asarray(shifts, float).reshape(-1, 3) if np.size(shifts) else np.zeros((0, 3))
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"P must have shape (h,3), got {P.shape}")
    if a.ndim != 1 or t.shape != (len(a), 3) or not (np.isfinite(a).all() and np.isfinite(t).all()):
        raise ValueError(f"angles (k,) and shifts (k,3) must be finite and match, got {a.shape} and {np.shape(shifts)}")
    i, j = _across(axis)
    c = P.mean(axis=0)
    R = np.zeros((len(a), 3, 3))
    R[:, axis, axis] = 1.0
    R[:, i, i] = R[:, j, j] = np.cos(a)
    R[:, j, i] = np.sin(a)
    R[:, i, j] = -np.sin(a)
    return np.einsum("kab,hb->kha", R, P - c) + c + t[:, None, :]


def twist_bend_samples(P, angle, shift, m, rng, axis=0, jitter=0.02):
    """m training configurations of a rigid 3D handle patch (a beam's end): twists uniform in [−angle, angle]
    and shifts uniform in the disc of radius ``shift`` across the beam (perpendicular to ``axis``);
    :func:`patch_motions` of those, then each handle moved on its own, uniformly in a ball of radius ``jitter``.

    The samples a user's own 3D model needs when its moving handles are a patch that turns and shifts as one
    piece: pass them as ``train(shape, ..., samples=Q)``.

    Rigid motions alone span a 3-parameter family: their Q_k lie in a 4-dimensional affine subspace of R^{3h}
    (cos and sin of the twist, two shifts), which no linear or TPS Ψ on R^{3h} can be fitted to; the jitter makes
    the samples determine Ψ.

    Parameters
    ----------
    P : (h,3) array_like
        Rest positions of the patch's handles (the moving handles, in the shape's order).
    angle, shift : float
        Largest twist (radians, below pi) and largest sideways shift.
    m : int
        Number of samples, at least 1.
    rng : numpy.random.Generator
        All randomness goes through it.
    axis : int
        0, 1 or 2: the beam's axis (the twist's axis).
    jitter : float
        Radius of each handle's own ball (0: rigid motions only).

    Returns
    -------
    Q : (m,h,3) numpy array

    Raises
    ------
    ValueError
        m not a positive integer, angle outside [0, pi), shift or jitter negative (or NaN), or P not (h,3).
    """
    if int(m) != m or m < 1 or not 0 <= angle < np.pi or not shift >= 0 or not jitter >= 0:
        raise ValueError(
            f"need m >= 1, 0 <= angle < pi, shift >= 0 and jitter >= 0, got m={m}, angle={angle}, shift={shift}, "
            f"jitter={jitter}"
        )
    i, j = _across(axis)
    a = rng.uniform(-angle, angle, size=m)
    r, phi = shift * np.sqrt(rng.uniform(size=m)), rng.uniform(0, 2 * np.pi, size=m)
    t = np.zeros((m, 3))
    t[:, i], t[:, j] = r * np.cos(phi), r * np.sin(phi)
    Q = patch_motions(P, a, t, axis)
    u = rng.normal(size=Q.shape)
    u *= jitter * rng.uniform(size=Q.shape[:2] + (1,)) ** (1 / 3) / np.linalg.norm(u, axis=-1, keepdims=True)
    return Q + u
