"""Handles of a shape: their vertex indices, the vertex nearest each handle point, the 3D span check and the
handle patches.

In 3D a handle is a patch of vertices that move together (a beam's end face, a hand): :func:`patches` groups the
moving handles into :class:`Patches`, each with its rest centre and every member's rest offset from it. A patch
moves rigidly, ``q = c + t + R (p - c)``, so its members keep their offsets up to the rotation R (training samples
it so, :func:`defop.training.sampling.rigid_patch_samples`), and a patch moved at rest moves every member by one
shared offset. In 2D a handle is a point: every moving handle is a patch of its own.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .. import options as opt

__all__ = ["Patches", "check_handles_span", "handle_vertices", "handle_indices", "patches"]


def check_handles_span(P):
    """Raise ValueError if the handle points P (h,3) lie on one line (or are fewer than 3).

    Point handles fix positions only: a rotation about a line through all of them costs nothing, so
    the variational problem has no unique minimum (its Hessian is singular).
    """
    P = np.asarray(P, float)
    if len(P) >= 3:
        D = P - P[0]
        len2 = D[:, 0] * D[:, 0] + D[:, 1] * D[:, 1] + D[:, 2] * D[:, 2]
        u = D[int(np.argmax(len2))]
        C = np.column_stack(
            [D[:, 1] * u[2] - D[:, 2] * u[1], D[:, 2] * u[0] - D[:, 0] * u[2], D[:, 0] * u[1] - D[:, 1] * u[0]]
        )
        off = np.sqrt((C[:, 0] * C[:, 0] + C[:, 1] * C[:, 1] + C[:, 2] * C[:, 2]) / max(float(len2.max()), 1e-300))
        if off.max() > 1e-9 * np.sqrt(max(float(len2.max()), 1e-300)):
            return
    what = f"the {len(P)} handles lie on one line" if len(P) > 1 else "a single handle"
    raise ValueError(
        f"{what}: in 3D a rotation about a line through them costs nothing (the Hessian is singular); "
        "use at least 3 handles that are not collinear (for example a small patch of handles)"
    )


def handle_vertices(mesh, points, tolerance=0.5):
    """The mesh vertex of each handle point (the nearest one); ValueError for points outside the mesh.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    points : (h,d) numpy array
    tolerance : float
        A point outside the mesh is accepted if its nearest vertex is at most ``tolerance`` × the typical
        edge length away (the snapped boundary of a tetrahedral mesh may pass just inside a surface point).

    Returns
    -------
    idx : (h,) int64 numpy array
    """
    H = opt.real_array("handles", points)
    if H.ndim != 2 or H.shape[1] != mesh.dim or len(H) == 0:
        raise ValueError(f"handles must have shape (h,{mesh.dim}), got {np.shape(points)}")
    if not np.isfinite(H).all():
        raise ValueError("handles have NaN or infinite entries")
    idx, dist = mesh.nearest_vertex(H)
    edge = (6 * float(np.median(mesh.volumes))) ** (1 / 3) if mesh.dim == 3 else np.sqrt(2 * np.median(mesh.volumes))
    outside = ~mesh.contains(H) & (dist > tolerance * edge)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise ValueError(f"handle {k} is outside the mesh (nearest vertex is {dist[k]:.3g} away)")
    uniq, first, counts = np.unique(idx, return_index=True, return_counts=True)
    if (counts > 1).any():
        v = int(uniq[counts > 1][0])
        a, b = np.flatnonzero(idx == v)[:2]
        raise ValueError(
            f"handles {a} and {b} both become vertex {v} (the nearest to each): move them apart or use more vertices"
        )
    return idx


def handle_indices(handles, n):
    """Handle vertex indices as an int64 array: integers (or integral floats), or a boolean mask.

    Parameters
    ----------
    handles : (h,) int array-like or (n,) bool array-like
    n : int
        Number of mesh vertices.

    Returns
    -------
    idx : (h,) int64 numpy array

    Raises
    ------
    ValueError
        A non-integral index (1.7 is not truncated to 1), a mask of the wrong length, or another dtype.
    """
    h = np.asarray(handles)
    if h.dtype == bool:
        if h.shape != (n,):
            raise ValueError(f"a boolean handle mask needs one entry per vertex ({n}), got shape {h.shape}")
        return np.flatnonzero(h).astype(np.int64)
    h = h.ravel()
    if np.issubdtype(h.dtype, np.floating):
        bad = ~np.isfinite(h) | (h != np.round(h))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"handle {k} is {h[k].item()!r}, not an integer vertex index")
    elif not np.issubdtype(h.dtype, np.integer):
        raise ValueError(f"handles must be integer vertex indices or a boolean mask, got dtype {h.dtype}")
    return h.astype(np.int64)


@dataclasses.dataclass(frozen=True, eq=False)
class Patches:
    """The moving handles of a shape grouped into patches that move as one piece.

    Attributes
    ----------
    members : tuple of (k,) int64 numpy arrays
        Per patch, its rows of the moving handles (``shape.P_moving``), increasing; patches ordered by their first
        member. Every moving handle is in exactly one patch.
    vertices : tuple of (k,) int64 numpy arrays
        Per patch, its members' mesh vertices (``shape.moving_handles[members[i]]``).
    centres : (p,d) numpy array
        Per patch, the rest centre c (the mean of its members' rest positions).
    offsets : (n,d) numpy array
        Per moving handle, its rest offset p - c from its patch's centre.
    radii : (p,) numpy array
        Per patch, the radius of its members' sampling balls (the smallest; NaN for a patch of one handle whose
        region is not a ball).
    """

    members: tuple
    vertices: tuple
    centres: np.ndarray
    offsets: np.ndarray
    radii: np.ndarray

    def __len__(self):
        return len(self.members)

    @property
    def rigid(self) -> bool:
        """Whether some patch has more than one handle (else every handle moves on its own)."""
        return any(len(k) > 1 for k in self.members)

    def of(self):
        """(n,) int64 numpy array: the patch of each moving handle."""
        out = np.empty(len(self.offsets), np.int64)
        for i, k in enumerate(self.members):
            out[k] = i
        return out


def patches(shape):
    """The handle patches of a shape's moving handles (see :class:`Patches`).

    In 3D two moving handles are in one patch when their sampling balls overlap (centre distance below the sum of
    their radii), and patches are the connected groups of that relation: ``bar_3d``'s 4 moving handles on its end
    face (balls of 0.12, 0.12 apart) are one patch, the 8 arm tips of ``octopus_3d`` 8 patches of one. A handle
    whose region is not a ball, and every handle in 2D (a point handle), is a patch of its own.

    Parameters
    ----------
    shape : defop.scene.shape.Shape

    Returns
    -------
    Patches
    """
    P = np.asarray(shape.P_moving, float)
    n, d = P.shape
    radius = np.array([float(r.radius) if r.kind in ("ball", "disc") else np.nan for r in shape.regions])
    ball = np.isfinite(radius)
    rows, cols = [], []
    if d == 3:
        for i in np.flatnonzero(ball):
            for j in np.flatnonzero(ball):
                if i < j and np.sqrt(((P[i] - P[j]) ** 2).sum()) < radius[i] + radius[j]:
                    rows.append(i)
                    cols.append(j)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    first = {}
    for i, lab in enumerate(label):
        first.setdefault(int(lab), []).append(i)
    members = tuple(np.array(k, np.int64) for k in first.values())  # ordered by first member
    centres = np.array([P[k].mean(axis=0) for k in members]).reshape(len(members), d)
    offsets = np.empty_like(P)
    for i, k in enumerate(members):
        offsets[k] = P[k] - centres[i]
    radii = np.array([radius[k].min() for k in members])
    vertices = tuple(np.asarray(shape.moving_handles)[k] for k in members)
    return Patches(members, vertices, centres, offsets, radii)
