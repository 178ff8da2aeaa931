"""Training handle configurations Q_k (§3.3).

Each Q_k is drawn independently per moving handle l, around its rest position p_l, from the handle's
region (:mod:`defop.scene.regions`; 2D or 3D, d read from P): uniform in a disc or ball, on a circle,
Gaussian, uniform in the Voronoi cell of p_l with respect to the other moving handles (clipped to a ball),
or a mixture of these (Fig. 1 mixes discs and Voronoi cells).

In 3D a handle is a patch of vertices (:func:`defop.scene.handles.patches`), and a shape's default sampling
(:func:`sample_shape`, ``sampling="auto"``) moves each patch of several handles rigidly
(:func:`rigid_patch_samples`: a rotation about its centre and a translation, each in a ball of the region's size,
plus a small jitter per handle); ``sampling="per_handle"`` draws every handle from its own region instead, which
tears a patch apart (its handles move independently by up to the region's radius, farther than the patch is wide).
A beam's end that twists and bends is sampled by :func:`twist_bend_samples` (rigid motions from
:func:`patch_motions` about the beam's axis). Fixed handles are not variables: they stay at rest and are not part
of Q. All randomness goes through the ``rng`` argument (a ``numpy.random.Generator``).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from ..scene.handles import patches
from ..scene.regions import as_region

#: the ways :func:`sample_shape` draws a shape's samples: ``"auto"`` (rigid patches where a patch has several
#: handles, else per handle), ``"rigid"`` (:func:`rigid_patch_samples`) and ``"per_handle"`` (:func:`sample_handles`)
SAMPLINGS = ("auto", "rigid", "per_handle")

#: the largest rotation of a rigid patch sample, radians (:func:`rigid_patch_samples`)
MAX_TURN = np.pi / 2

#: the jitter of each handle of a rigid patch sample, as a fraction of its patch's radius
PATCH_JITTER = 0.04


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


def sample_shape(shape, m, rng, sampling="auto"):
    """m configurations of a :class:`defop.scene.shapes.Shape`'s moving handles, from its regions.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    m : int
    rng : numpy.random.Generator or int
    sampling : str
        ``"per_handle"``: each moving handle independently from its own region (:func:`sample_handles`).
        ``"rigid"``: each handle patch (:func:`defop.scene.handles.patches`) moved rigidly
        (:func:`rigid_patch_samples`). ``"auto"`` (default): ``"rigid"`` when some patch has several handles (a
        3D shape with a handle patch, such as ``bar_3d``), else ``"per_handle"`` (every 2D shape: the same samples
        as before patches existed).

    Returns
    -------
    Q : (m,n,d) numpy array
    """
    opt.choice("sampling", sampling, SAMPLINGS)
    if sampling == "per_handle":
        return sample_handles(shape.P_moving, shape.regions, m, rng)
    groups = patches(shape)
    if sampling == "auto" and not groups.rigid:
        return sample_handles(shape.P_moving, shape.regions, m, rng)
    return rigid_patch_samples(groups, m, rng, regions=shape.regions)


def rigid_patch_samples(groups, m, rng, jitter=PATCH_JITTER, max_turn=MAX_TURN, regions=None):
    """m configurations of handle patches, each moved rigidly: q = c + t + R (p - c) for its members p.

    Per sample and patch: a translation t uniform in the ball of the patch's radius r (its regions' radius) and
    a rotation R about the centre c by the rotation vector uniform in the ball of radius
    ``min(max_turn, 2 asin(r / 2ρ))`` (ρ the patch's largest rest offset: no member is turned farther than r);
    then each member moves on its own, uniformly in a ball of ``jitter`` × r (rigid motions alone lie on a
    6-dimensional set, on which no Ψ on R^{3k} is determined). A patch of one handle is drawn from its own region.

    Parameters
    ----------
    groups : defop.scene.handles.Patches
    m : int
    rng : numpy.random.Generator or int
    jitter : float
        Each member's own ball, a fraction of r (0: rigid motions only, the held-out distribution).
    max_turn : float
        The largest rotation angle, radians, in [0, pi].
    regions : list of defop.scene.regions.Region, optional
        The moving handles' regions (needed for patches of one handle whose region is not a ball).

    Returns
    -------
    Q : (m,n,d) numpy array

    Raises
    ------
    ValueError
        m not a positive integer, jitter negative, max_turn outside [0, pi], a patch of several handles not in 3D,
        or a patch of one non-ball handle without ``regions``.
    """
    m = opt.integer("m", m, minimum=1)
    if not jitter >= 0 or not 0 <= max_turn <= np.pi:
        raise ValueError(f"need jitter >= 0 and 0 <= max_turn <= pi, got jitter={jitter!r}, max_turn={max_turn!r}")
    rng = opt.rng(rng)
    n, d = groups.offsets.shape
    Q = np.empty((m, n, d))
    P = groups.centres[groups.of()] + groups.offsets
    for i, k in enumerate(groups.members):
        c, r = groups.centres[i], float(groups.radii[i])
        if len(k) == 1:
            region = {"kind": "ball", "radius": r} if regions is None else regions[k[0]]
            if not np.isfinite(r) and regions is None:
                raise ValueError(f"patch {i} (moving handle {int(k[0])}) has no ball region: pass regions")
            Q[:, k[0]] = as_region(region).sample(rng, c, m, P, int(k[0]))
            continue
        if d != 3:
            raise ValueError(f"a rigid patch of several handles is a 3D concept, got d = {d}")
        off = groups.offsets[k]
        rho = float(np.sqrt((off * off).sum(axis=1)).max())
        turn = min(max_turn, 2 * np.arcsin(min(1.0, r / (2 * rho)))) if rho > 0 else 0.0
        t = as_region({"kind": "ball", "radius": r}).sample(rng, np.zeros(3), m)
        w = as_region({"kind": "ball", "radius": max(turn, 1e-300)}).sample(rng, np.zeros(3), m) * (turn > 0)
        q = c + t[:, None, :] + np.einsum("mab,kb->mka", rotations(w), off)
        if jitter > 0:
            q = q + as_region({"kind": "ball", "radius": jitter * r}).sample(rng, np.zeros(3), m * len(k)).reshape(
                m, len(k), 3
            )
        Q[:, k] = q
    return Q


def rotations(w):
    """(m,3,3) rotation matrices of rotation vectors w (m,3) (Rodrigues' formula; the axis w/|w|, the angle |w|)."""
    w = np.asarray(w, float).reshape(-1, 3)
    a = np.sqrt((w * w).sum(axis=1))
    u = w / np.where(a > 0, a, 1.0)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = u[:, 2], -u[:, 1], u[:, 0]
    s, c = np.sin(a)[:, None, None], np.cos(a)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * np.einsum("mab,mbc->mac", K, K)


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

    A beam's end that turns about the beam's axis and shifts across it: pass them as ``train(shape, ...,
    samples=Q)``. ``train``'s default already moves every handle patch rigidly, about any axis
    (:func:`rigid_patch_samples`).

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
