"""The input checks shared by the rival methods: point arrays, handle sets, handle positions and their span.

Every method works on triangle meshes (d = 2) and tetrahedral meshes (d = 3), reading d from the data (the
columns of V, or ``mesh.dim``). Point handles fix positions only: linear precision (TPS, biharmonic coordinates)
needs handles that span R^d (not on one line in 2D, not on one plane in 3D).
"""

from __future__ import annotations

import numpy as np

from .. import options as opt

__all__ = ["check_handles", "check_points", "check_positions", "check_span", "dim_hint", "dim_of", "mesh_arrays"]


def dim_of(A):
    """d of a point array: its number of columns when that is 2 or 3, else 2 (the error then names (n, 2))."""
    shape = np.shape(A)
    return shape[1] if len(shape) == 2 and shape[1] in (2, 3) else 2


def check_points(A, name, n=None, d=None):
    """``A`` as a float (n,d) point array (d from :func:`dim_of` unless given); ValueError naming ``name``."""
    return opt.points(name, A, n=n, d=dim_of(A) if d is None else d)


def check_handles(P, min_count=1, method="this method", d=None):
    """Handle positions P (h,d): at least ``min_count`` of them (``method`` names who needs them), none coincide."""
    P = check_points(P, "P", d=d)
    if len(P) < min_count:
        raise ValueError(f"{method} needs at least {min_count} handles, got {len(P)}")
    dist = np.linalg.norm(P[:, None] - P[None], axis=-1) + np.eye(len(P))
    i, j = np.unravel_index(np.argmin(dist), dist.shape)
    if len(P) > 1 and dist[i, j] < 1e-12 * max(1.0, np.abs(P).max()):
        raise ValueError(f"handles {min(i, j)} and {max(i, j)} coincide at {P[i].tolist()}")
    return P


def check_positions(Q, h, d=2):
    """Positions Q (h,d) of all h handles, finite; ValueError naming Q otherwise."""
    Q = opt.real_array("Q", Q)
    if Q.shape != (h, d):
        raise ValueError(f"Q must have shape ({h}, {d}) for the {h} handles, got {Q.shape}{dim_hint(Q, h, d)}")
    if not np.isfinite(Q).all():
        raise ValueError("Q has NaN or infinite entries")
    return Q


def dim_hint(Q, h, d):
    """The clause naming a Q of h rows in the wrong dimension (a 2D Q for a 3D mesh, or the reverse), else ''."""
    return f" (a {d}D mesh needs {d}D handle positions)" if np.ndim(Q) == 2 and np.shape(Q)[0] == h else ""


#: what handles that fail to span k dimensions lie on
_FLAT = {0: "one point", 1: "one line", 2: "one plane"}


def check_span(P, k, method, why):
    """Refuse handles P (h,d) whose affine hull has dimension < k (singular values of the centred P).

    ``method`` is the subject and verb of the message, e.g. ``"the TPS warp needs"``.
    """
    sv = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    if len(sv) < k or sv[k - 1] <= 1e-9 * max(sv[0], np.finfo(float).tiny):
        spread = f" (spread across it {sv[k - 1]:.2g}, along it {sv[0]:.2g})" if len(sv) >= k else ""
        raise ValueError(
            f"{method} handles that are not all on {_FLAT[k - 1]} ({why}); the {len(P)} handles "
            f"lie on {_FLAT[k - 1]}{spread}; move one off it"
        )


def mesh_arrays(mesh, handles):
    """(V, F, b): the mesh's arrays as libigl takes them and the handle indices b, distinct vertices, checked."""
    V = np.ascontiguousarray(mesh.V, dtype=float)
    F = np.ascontiguousarray(mesh.F, dtype=np.int64)
    b = np.asarray(handles, dtype=np.int64).ravel()
    if len(b) == 0 or b.min() < 0 or b.max() >= len(V):
        raise ValueError(f"handles must be vertex indices in [0, {len(V)}), got {b.tolist()}")
    if len(np.unique(b)) != len(b):
        raise ValueError("a vertex is given as a handle twice")
    check_handles(V[b])
    return V, F, b
