"""A structured tetrahedral mesh: cubes of a regular grid, each split into the 6 Kuhn tetrahedra.

The Kuhn (Freudenthal) split of the unit cube has one tetrahedron per ordering of the axes: from the
corner (0,0,0) along the axes in that order to (1,1,1). Every square face of a cube is split along
the same diagonal (from its lowest to its highest corner) in both cubes sharing it, so neighbouring
cubes' tetrahedra match face to face and any set of cubes gives a conforming mesh.

Which cubes to keep is a boolean array over the grid. :func:`clean_cubes` makes the set one solid
whose boundary is a closed 2-manifold: it fills cavities, keeps the largest face-connected piece and
removes the critical configurations of Latecki's well-composed sets (two cubes sharing only an edge
or only a corner), which are exactly where a boundary would pinch. Everything is integer logic and
element-wise arithmetic: the same mesh on every CPU.
"""

from __future__ import annotations

from itertools import permutations

import numpy as np
from scipy import ndimage

__all__ = ["kuhn_tets", "clean_cubes", "cubes_to_tets", "grid_centres"]

# corner c of the unit cube is (c & 1, c >> 1 & 1, c >> 2 & 1)
_CORNERS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])


def kuhn_tets():
    """(6, 4) int numpy array: the Kuhn tetrahedra of the unit cube, as corner indices x + 2y + 4z.

    Each goes from corner 0 to corner 7 adding one axis at a time; all are positively oriented
    (volume 1/6 each).
    """
    tets = []
    for axes in permutations(range(3)):
        c, tet = 0, [0]
        for a in axes:
            c += 1 << a
            tet.append(c)
        P = _CORNERS[tet]
        e = P[1:] - P[0]
        det = (
            e[0, 0] * (e[1, 1] * e[2, 2] - e[1, 2] * e[2, 1])
            - e[0, 1] * (e[1, 0] * e[2, 2] - e[1, 2] * e[2, 0])
            + e[0, 2] * (e[1, 0] * e[2, 1] - e[1, 1] * e[2, 0])
        )
        tets.append(tet if det > 0 else [tet[0], tet[2], tet[1], tet[3]])
    return np.array(tets, dtype=np.int64)


def grid_centres(lo, h, shape):
    """(nx·ny·nz, 3) numpy array: the cube centres lo + (i + ½) h, x fastest (element-wise)."""
    k, j, i = np.meshgrid(*(np.arange(s) for s in shape[::-1]), indexing="ij")
    idx = np.column_stack([i.ravel(), j.ravel(), k.ravel()])
    return np.asarray(lo, float) + (idx + 0.5) * h


def _fill_and_keep_largest(occ):
    """Fill cavities (cells not face-connected to the border of the grid), keep the largest solid."""
    empty, _ = ndimage.label(~occ)
    border = np.concatenate([empty[[0, -1]].ravel(), empty[:, [0, -1]].ravel(), empty[..., [0, -1]].ravel()])
    outside = np.unique(border)
    occ = occ | ~np.isin(empty, outside[outside > 0])
    solid, n = ndimage.label(occ)
    if n > 1:
        sizes = np.bincount(solid.ravel())[1:]
        occ = solid == 1 + int(np.argmax(sizes))
    return occ


def _shifted(shape, offset):
    """Slices selecting, for every interior grid vertex, the cube at ``offset`` (0/1 per axis) around it."""
    return tuple(slice(o, n - 1 + o) for n, o in zip(shape, offset))


def _critical_fixes(occ):
    """Cubes to add so that no two cubes meet only along an edge or only at a corner (well-composed).

    At every interior grid vertex, look at the 2×2×2 block of cubes around it. The block is filled
    when two diagonal cubes of one of its 2×2 slices are in and the other two out (they meet along
    an edge only), when only two antipodal cubes are in, or when only two antipodal cubes are out
    (the boundary pinches at the vertex). Returns a boolean array like ``occ``.
    """
    cube = [occ[_shifted(occ.shape, _CORNERS[c])] for c in range(8)]
    count = sum(x.astype(np.int8) for x in cube)
    bad = np.zeros_like(cube[0])
    for ax in range(3):  # the two 2x2 slices of the block across each axis: their diagonal pairs
        for lo in (0, 1 << ax):
            others = [c for c in range(8) if c & (1 << ax) == lo]
            a, b, c, d = (cube[k] for k in others)  # corners ordered by their two free bits: 00, 01, 10, 11
            bad |= (a & d & ~b & ~c) | (b & c & ~a & ~d)
    for c in range(4):  # antipodal pairs (c, 7 - c)
        pair_in, pair_out = cube[c] & cube[7 - c], ~cube[c] & ~cube[7 - c]
        bad |= (pair_in & (count == 2)) | (pair_out & (count == 6))
    add = np.zeros_like(occ)
    for c in range(8):
        add[_shifted(occ.shape, _CORNERS[c])] |= bad
    return add & ~occ


def clean_cubes(occ, max_rounds=100):
    """One solid with a closed 2-manifold boundary, from a boolean array of cubes.

    Adds cubes where the boundary would pinch (:func:`_critical_fixes`: pieces meeting at an edge or
    a corner are joined), fills cavities and keeps the largest face-connected piece, until nothing
    changes. The grid must have at least two empty layers around the solid.

    Parameters
    ----------
    occ : (nx, ny, nz) bool numpy array

    Returns
    -------
    occ : (nx, ny, nz) bool numpy array
    """
    occ = np.asarray(occ, bool)
    for _ in range(max_rounds):
        add = _critical_fixes(occ)  # first: cubes meeting at an edge or a corner become one piece
        cleaned = _fill_and_keep_largest(occ | add)
        if not add.any() and np.array_equal(cleaned, occ):
            return occ
        occ = cleaned
    raise RuntimeError(f"the cube set did not become well-composed in {max_rounds} rounds")


def cubes_to_tets(occ, lo, h):
    """The Kuhn tetrahedra of the kept cubes, with only the grid vertices they use.

    Parameters
    ----------
    occ : (nx, ny, nz) bool numpy array
        Cube (i, j, k) spans lo + [i, i+1] h × [j, j+1] h × [k, k+1] h.
    lo : (3,) array-like
    h : float

    Returns
    -------
    V : (n, 3) numpy array
        Grid vertices, ordered by (z, y, x) index.
    T : (m, 4) int numpy array
        Positively oriented tetrahedra, 6 per cube in cube order (x fastest).
    """
    nx, ny, nz = occ.shape
    k, j, i = np.nonzero(np.transpose(occ, (2, 1, 0)))  # cubes in order x fastest
    base = i + (nx + 1) * (j + (ny + 1) * k)
    offs = _CORNERS[:, 0] + (nx + 1) * (_CORNERS[:, 1] + (ny + 1) * _CORNERS[:, 2])
    T = (base[:, None, None] + offs[kuhn_tets()][None]).reshape(-1, 4)
    used, T = np.unique(T, return_inverse=True)
    T = T.reshape(-1, 4)
    gi = used % (nx + 1)
    gj = (used // (nx + 1)) % (ny + 1)
    gk = used // ((nx + 1) * (ny + 1))
    V = np.asarray(lo, float) + np.column_stack([gi, gj, gk]) * h
    return V, T.astype(np.int64)
