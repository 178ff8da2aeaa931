"""Handles placed automatically, by one rule in 2D and 3D: the shape's extremities, as patches in 3D.

:func:`extremities` picks boundary vertices far apart, one at a time, each maximising its distance to the nearest
vertex picked so far plus its distance to the centroid of the mesh's vertices (farthest-point sampling, Euclidean,
with the centroid term so that an extremity wins over a concave corner as far from the picks; the first pick is the
boundary vertex farthest from the centroid). On a star these are its tips, on an octopus its arms' ends.
:func:`patches` grows each into a handle: in 2D the vertex itself, in 3D a patch of :data:`PATCH_SIZE` vertices (the
vertex and its nearest ones, as ``bar_3d``'s end faces hold 4 handles), since a point handle in a solid is a pin a
tetrahedral mesh can turn about.

Every distance is summed element-wise (no BLAS), so the picks are the same on every CPU; ties go to the lowest
vertex index.
"""

from __future__ import annotations

import numpy as np

from .. import options as opt

__all__ = ["DEFAULT_COUNT", "PATCH_SIZE", "extremities", "patches", "automatic_handles"]

#: vertices of an automatic 3D handle patch
PATCH_SIZE = 4

#: how many handles (patches in 3D) :func:`defop.scene.own_input.load_model` places by default
DEFAULT_COUNT = {2: 4, 3: 3}


def _sq_dist(P, c):
    """|P − c|² row by row, P (k,d), c (d,), element-wise."""
    D = P - c
    out = D[:, 0] * D[:, 0]
    for j in range(1, D.shape[1]):
        out = out + D[:, j] * D[:, j]
    return out


def extremities(mesh, k):
    """k boundary vertices of ``mesh`` far apart and far from the centroid (see the module docstring).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
        2D (triangles) or 3D (tetrahedra).
    k : int
        How many, 1 to the number of boundary vertices.

    Returns
    -------
    idx : (k,) int64 numpy array
        Vertex indices, in the order picked (the first is the extremity farthest from the centroid).
    """
    B = mesh.boundary_vertices
    k = opt.integer("number of automatic handles", k, minimum=1, maximum=len(B))
    V = mesh.V
    centroid = np.array([float(np.sum(V[:, j])) / len(V) for j in range(V.shape[1])])
    outward = np.sqrt(_sq_dist(V[B], centroid))
    nearest = np.zeros(len(B))  # to the picks so far: none yet
    picks = []
    for _ in range(k):
        picks.append(int(np.argmax(nearest + outward)))
        d = np.sqrt(_sq_dist(V[B], V[B[picks[-1]]]))
        nearest = d if len(picks) == 1 else np.minimum(nearest, d)
    return B[np.array(picks, np.int64)]


def patches(mesh, seeds, size=None):
    """A handle grown around each seed vertex: the seed and its ``size − 1`` nearest mesh vertices.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    seeds : (h,) int numpy array
        Vertex indices.
    size : int, optional
        Vertices per handle (default: 1 in 2D, :data:`PATCH_SIZE` in 3D).

    Returns
    -------
    groups : list of (size,) int64 numpy array
        One per seed, the seed first.

    Raises
    ------
    ValueError
        Two patches share a vertex (the seeds are too close for this size: fewer or smaller patches, or a finer
        mesh).
    """
    size = (1 if mesh.dim == 2 else PATCH_SIZE) if size is None else size
    size = opt.integer("patch_size", size, minimum=1, maximum=mesh.n_vertices)
    groups = []
    for s in np.asarray(seeds, np.int64):
        d = _sq_dist(mesh.V, mesh.V[s])
        order = np.argsort(d, kind="stable")
        order = order[order != s]
        groups.append(np.concatenate([[s], order[: size - 1]]).astype(np.int64))
    flat = np.concatenate(groups)
    uniq, counts = np.unique(flat, return_counts=True)
    if (counts > 1).any():
        v = int(uniq[counts > 1][0])
        raise ValueError(
            f"handle patches of {size} vertices overlap at vertex {v}: place fewer handles, smaller patches "
            "(patch_size) or use more vertices"
        )
    return groups


def automatic_handles(mesh, k, size=None):
    """:func:`extremities` grown into :func:`patches`: (groups, the flat vertex indices of every handle)."""
    groups = patches(mesh, extremities(mesh, k), size)
    return groups, np.concatenate(groups)
