"""Vertex welding: exactly coincident coordinates, or opt-in within a tolerance that must not break the surface."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["bbox_diagonal", "weld"]


def bbox_diagonal(V):
    """The bounding-box diagonal of V (n, d), computed without overflow or underflow (coordinates scaled by their
    largest magnitude): the one such computation of the package (welding, the coordinate range, the Laplacian)."""
    s = float(np.abs(V).max(initial=0.0))
    return s * float(np.linalg.norm(np.ptp(V / s, axis=0))) if s > 0 else 0.0


def weld(V, F, tolerance=0.0):
    """Merge vertices at exactly the same coordinates, and optionally those within a tolerance.

    Parameters
    ----------
    V : (n, 3) numpy array
    F : (k, 3) int numpy array
    tolerance : float
        Also merge vertices closer than ``tolerance`` × the bounding-box diagonal (0: exact only). Each
        cluster of vertices linked by such distances becomes its first vertex.

    Returns
    -------
    V : (n', 3) numpy array
        The kept vertices, in the order of their first appearance.
    F : (k, 3) int numpy array
    welded : int
        n - n', how many vertices were merged into others.

    Raises
    ------
    ValueError
        Tolerance welding that makes a triangle degenerate (two corners merged) or an edge shared by
        more than two triangles; the message names the triangle or edge.
    """
    V, F = np.asarray(V, dtype=np.float64) + 0.0, np.asarray(F, dtype=np.int64)  # + 0.0: -0.0 becomes 0.0
    exact = _merge(V, F, np.unique(V, axis=0, return_inverse=True)[1].ravel())
    if not tolerance > 0:
        return exact
    # clusters of vertices linked by distances <= the tolerance (exact copies included)
    pairs = cKDTree(V).query_pairs(tolerance * bbox_diagonal(V), output_type="ndarray")
    G = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(V), len(V)))
    near = _merge(V, F, connected_components(G, directed=False)[1])
    _check_tolerance_weld(exact[1], near[1], tolerance)
    return near


def _merge(V, F, label):
    """Each group of vertices with one label becomes its first vertex (in order of first appearance)."""
    _, first = np.unique(label, return_index=True)
    keep = np.sort(first)
    rank = np.empty(len(first), dtype=np.int64)
    rank[label[keep]] = np.arange(len(keep))
    return np.ascontiguousarray(V[keep]), rank[label][F], len(V) - len(keep)


def _check_tolerance_weld(F, F2, tolerance):
    degenerate = (F2[:, 0] == F2[:, 1]) | (F2[:, 1] == F2[:, 2]) | (F2[:, 2] == F2[:, 0])
    before = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    bad = np.flatnonzero(degenerate & ~before)
    if len(bad):
        raise ValueError(
            f"welding within {tolerance:g} × the diagonal makes {len(bad)} triangles degenerate "
            f"(two corners merged), first is triangle {int(bad[0])}; use a smaller weld_tolerance"
        )
    E = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(E, axis=0, return_counts=True)
    E0 = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    if (counts > 2).any() and counts.max() > np.unique(E0, axis=0, return_counts=True)[1].max():
        k = int(np.flatnonzero(counts > 2)[0])
        raise ValueError(
            f"welding within {tolerance:g} × the diagonal puts edge ({int(uniq[k, 0])}, "
            f"{int(uniq[k, 1])}) in {int(counts[k])} triangles (not a manifold); use a smaller "
            "weld_tolerance"
        )
