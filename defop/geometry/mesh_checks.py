"""Checks of a mesh's arrays: shapes, indices, orientation and manifoldness, each error naming the element,
edge, triangle or vertex at fault."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .simplices import ELEMENT, ELEMENTS, element_facets

__all__ = [
    "dim_of",
    "check_vertices",
    "check_elements",
    "orient_elements",
    "check_triangle_manifold",
    "check_tet_manifold",
    "check_closed_surface",
]


def dim_of(V, F):
    """d from F's columns (3: triangles, 4: tetrahedra), else from V; V's columns must agree."""
    F_ = np.asarray(F)
    if F_.ndim == 2 and F_.shape[1] in (3, 4):
        return F_.shape[1] - 1
    V_ = np.asarray(V)
    return V_.shape[1] if V_.ndim == 2 and V_.shape[1] in (2, 3) else 2


def check_vertices(V, name="V", d=2, F_note=""):
    """V as a finite (n, d) float64 array; ValueError naming ``name``, the shape (with ``F_note``) or the first
    non-finite row."""
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != d:
        raise ValueError(f"{name} must have shape (n,{d}){F_note}, got {V.shape}")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ValueError(
            f"{name} has {int(bad.sum())} non-finite (NaN or inf) rows, first at row {int(np.flatnonzero(bad)[0])}"
        )
    return V


def check_elements(F, n, d=2):
    """F as an (m, d + 1) int64 array of indices into n vertices; ValueError naming the bad entry."""
    F = np.asarray(F)
    el, els = ELEMENT[d], ELEMENTS[d]
    if F.ndim != 2 or F.shape[1] != d + 1:
        raise ValueError(f"F must have shape (m,{d + 1}), got {F.shape}")
    if len(F) == 0:
        raise ValueError(f"F has no {els}")
    if F.dtype == bool or not (np.issubdtype(F.dtype, np.integer) or np.issubdtype(F.dtype, np.floating)):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    if not np.issubdtype(F.dtype, np.integer):
        bad = ~np.isfinite(F) | (F != np.round(F))
        if bad.any():
            t, j = (int(x) for x in np.argwhere(bad)[0])
            raise ValueError(f"F must hold integer vertex indices: {el} {t} has {F[t, j].item()!r}")
    bad = (F < 0) | (F >= n)
    if bad.any():
        t, j = (int(x) for x in np.argwhere(bad)[0])
        raise ValueError(
            f"{el} {t} indexes vertex {F[t, j].item()!r}, but V has {n} vertices (valid indices 0 to {n - 1})"
        )
    return F.astype(np.int64)


def orient_elements(F, a):
    """F positively oriented: all-negative input is flipped; a mix means inverted elements."""
    cw = a < 0
    if cw.all():
        return np.ascontiguousarray(F[:, [0, 2, 1, *range(3, F.shape[1])]])
    if cw.any():
        t = int(np.flatnonzero(cw)[0])
        if F.shape[1] == 3:
            raise ValueError(
                f"triangle {t} is inverted (clockwise, signed area {a[t]:.3g}) while {int((~cw).sum())} triangles "
                f"are counter-clockwise ({int(cw.sum())} inverted in all): the mesh folds over itself"
            )
        raise ValueError(
            f"tetrahedron {t} is inverted (signed volume {a[t]:.3g}) while {int((~cw).sum())} tetrahedra are "
            f"positively oriented ({int(cw.sum())} inverted in all): the mesh folds over itself"
        )
    return F


def check_triangle_manifold(F):
    """Every edge in at most two triangles, an interior edge used once in each direction, one fan per vertex."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    tri = np.tile(np.arange(len(F)), 3)
    key = np.sort(E, axis=1)
    uniq, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts > 2).any():
        k = int(np.flatnonzero(counts > 2)[0])
        ts = np.sort(tri[inv == k])
        raise ValueError(
            f"edge ({int(uniq[k, 0])}, {int(uniq[k, 1])}) is shared by {int(counts[k])} triangles "
            f"({', '.join(map(str, ts))}): the mesh is not a manifold"
        )
    boundary = uniq[counts == 1]
    per_vertex = np.bincount(boundary.ravel(), minlength=int(F.max()) + 1)
    if (per_vertex > 2).any():
        v = int(np.flatnonzero(per_vertex > 2)[0])
        raise ValueError(
            f"vertex {v} is not a manifold vertex: {int(per_vertex[v])} boundary edges meet there (its triangles "
            "form separate fans, as where two pieces touch at a corner)"
        )
    d_uniq, d_counts = np.unique(E, axis=0, return_counts=True)
    if (d_counts > 1).any():
        k = int(np.flatnonzero(d_counts > 1)[0])
        i, j = (int(x) for x in d_uniq[k])
        ts = np.sort(tri[(E[:, 0] == i) & (E[:, 1] == j)])
        raise ValueError(
            f"edge ({i}, {j}) is used in the same direction by triangles {', '.join(map(str, ts))}: "
            "their orientations disagree (the mesh folds over itself)"
        )


def check_tet_manifold(T):
    """Every triangle in at most two tetrahedra, from opposite sides; the boundary a closed manifold surface."""
    facets, tet = element_facets(T)
    uniq, inv, counts = np.unique(np.sort(facets, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts > 2).any():
        k = int(np.flatnonzero(counts > 2)[0])
        raise ValueError(
            f"triangle {tuple(int(x) for x in uniq[k])} is shared by {int(counts[k])} tetrahedra "
            f"({', '.join(map(str, np.sort(tet[inv == k])))}): the mesh is not a manifold"
        )
    shared = np.flatnonzero(counts[inv] == 2)
    if len(shared):  # two tetrahedra on the same side of their common triangle overlap
        order = np.argsort(inv[shared], kind="stable")
        a, b = shared[order[0::2]], shared[order[1::2]]
        same = _same_cyclic(facets[a], facets[b])
        if same.any():
            k = int(np.flatnonzero(same)[0])
            raise ValueError(
                f"tetrahedra {min(tet[a[k]], tet[b[k]])} and {max(tet[a[k]], tet[b[k]])} lie on the same side of "
                f"their common triangle {tuple(int(x) for x in np.sort(facets[a[k]]))}: the mesh folds over itself"
            )
    check_closed_surface(facets[counts[inv] == 1], what="the boundary surface of the tetrahedra")


def _same_cyclic(A, B):
    """(k,) bool: whether triangles A[i] and B[i] (same vertex set) have the same orientation."""
    return (A == B).all(axis=1) | (A == B[:, [1, 2, 0]]).all(axis=1) | (A == B[:, [2, 0, 1]]).all(axis=1)


def check_closed_surface(S, what="the surface"):
    """Raise ValueError unless the triangles S (k, 3) form a closed, oriented 2-manifold.

    Every edge lies in exactly two triangles that traverse it in opposite directions, and the
    triangles around each vertex form a single fan (no two pieces touching at a vertex).

    Parameters
    ----------
    S : (k, 3) int numpy array
        Triangles (indices into some vertex array).
    what : str
        How the message names the surface.
    """
    S = np.asarray(S, dtype=np.int64)
    E = np.concatenate([S[:, [0, 1]], S[:, [1, 2]], S[:, [2, 0]]])
    uniq, inv, counts = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (counts != 2).any():
        k = int(np.flatnonzero(counts != 2)[0])
        e, c = (int(uniq[k, 0]), int(uniq[k, 1])), int(counts[k])
        kind = (
            f"open: edge {e} lies in only 1 triangle" if c == 1 else f"not a manifold: edge {e} lies in {c} triangles"
        )
        ts = np.sort(np.tile(np.arange(len(S)), 3)[inv == k])
        raise ValueError(f"{what} is {kind} ({', '.join(map(str, ts))})")
    d_uniq, d_counts = np.unique(E, axis=0, return_counts=True)
    if (d_counts > 1).any():
        i, j = (int(x) for x in d_uniq[int(np.flatnonzero(d_counts > 1)[0])])
        raise ValueError(
            f"{what} is not consistently oriented: edge ({i}, {j}) is traversed in the same direction by two "
            "triangles (a flipped triangle or a Möbius-like fold)"
        )
    _check_single_fans(S, E, inv)


def _check_single_fans(S, E, inv):
    """Each vertex's triangles form one fan: corners (t, v) linked across the edges at v are one component."""
    k = len(S)
    order = np.argsort(inv, kind="stable")
    a, b = order[0::2], order[1::2]  # the two half-edges of every edge; half-edge h belongs to triangle h % k
    ta, tb = a % k, b % k
    # half-edge h = block*k + t runs S[t, block] -> S[t, (block+1)%3]; its ends are corners (t, block), (t, block+1)
    ja, jb = a // k, b // k
    # edge (u -> w) in triangle ta and (w -> u) in tb: corner (ta, u) ~ (tb, u), corner (ta, w) ~ (tb, w)
    src = np.concatenate([3 * ta + ja, 3 * ta + (ja + 1) % 3])
    dst = np.concatenate([3 * tb + (jb + 1) % 3, 3 * tb + jb])
    G = sp.coo_matrix((np.ones(len(src)), (src, dst)), shape=(3 * k, 3 * k))
    _, label = connected_components(G, directed=False)
    vertex = S.ravel()  # corner 3t + j is vertex S[t, j]
    pairs = np.unique(np.column_stack([vertex, label]), axis=0)
    fans = np.bincount(pairs[:, 0])
    if (fans > 1).any():
        v = int(np.flatnonzero(fans > 1)[0])
        raise ValueError(
            f"vertex {v} is not a manifold vertex: its triangles form {int(fans[v])} separate fans on the boundary "
            "surface (as where two pieces touch at a corner)"
        )
