"""Placement regions: where a movable handle's rest position p_ℓ may sit (§5's open question).

A *movable* handle has a placement region, a set of mesh vertices around its nominal rest position: the
vertices within a ball (a disc in 2D) of given radius that are connected to the handle inside that ball (a
ball that reaches across a gap into a neighbouring limb does not take the other limb's vertices), or a vertex
set given by the caller. Its rest position may be any vertex of the region; handles that are not movable
(fixed ones, and moving ones without a region) stay at their nominal vertex.

Rules, each checked with a ValueError that names the handle, the vertex and the broken condition:

* a region holds its own handle's nominal vertex and at least one vertex;
* regions do not overlap (two handles can never land on one vertex);
* no other handle (fixed, or moving but not movable) lies inside a region.

In 3D a handle is a patch of vertices that share one rest offset (:func:`defop.scene.handles.patches`): the
region is where the movable handle's own vertex may sit, and placing it at region vertex v moves every member of its
patch by the same offset V[v] − p⁰ (:func:`patch_layout`; a region vertex whose offset does not take every member
onto a mesh vertex is not in the region). In 2D every handle is a patch of its own and nothing changes.

Each member's vertex at each region vertex carries a correction bump g (:func:`bumps`): 1 at that vertex, 0 at every
vertex of the other regions, at every handle that is not movable and at the other members at the same placement,
a smooth function of the mesh's edge-graph distance in between. The movable operator
(:mod:`defop.operator.movable`) spreads each handle's residual with it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from .. import options as opt
from .handles import patches

#: a rest position given as a point snaps to the nearest region vertex within this share of the bbox diagonal
SNAP_TOL = 1e-6
#: the correction bump reaches at most this many times the region's radius (graph distance) from its vertex
BUMP_REACH = 2.0


def edge_graph(mesh):
    """The mesh's vertex adjacency weighted by edge length, (n_vertices, n_vertices) sparse CSR."""
    F = np.asarray(mesh.F)
    k = F.shape[1]
    E = np.concatenate([F[:, [a, b]] for a in range(k) for b in range(a + 1, k)])
    E = np.unique(np.sort(E, axis=1), axis=0)
    w = np.linalg.norm(mesh.V[E[:, 0]] - mesh.V[E[:, 1]], axis=1)
    n = mesh.n_vertices
    return sp.csr_matrix(
        (np.concatenate([w, w]), (np.concatenate([E[:, 0], E[:, 1]]), np.concatenate([E[:, 1], E[:, 0]]))), shape=(n, n)
    )


def patch_layout(mesh, handles, members, vertices):
    """Where the members of a movable patch land when its first member is placed at each of ``vertices``.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        All handles' nominal vertices.
    members : (s,) int numpy array
        The patch's handles (indices into ``handles``), the movable one first.
    vertices : (k,) int numpy array
        Candidate vertices of the movable handle.

    Returns
    -------
    layout : (k, s) int numpy array
        Per candidate, each member's vertex (the nearest to its nominal position plus the shared offset).
    exact : (k,) bool numpy array
        Whether every member lands on its vertex within :data:`SNAP_TOL` of the bounding-box diagonal.
    """
    V = mesh.V
    p0 = V[handles[members]]  # (s, d)
    target = V[vertices][:, None, :] + (p0 - p0[0])  # (k, s, d): one shared offset
    if len(members) == 1:
        return np.asarray(vertices, np.int64)[:, None], np.ones(len(vertices), bool)
    idx, dist = mesh.nearest_vertex(target.reshape(-1, mesh.dim))
    exact = (dist.reshape(len(vertices), -1) <= SNAP_TOL * mesh.bbox_diagonal).all(axis=1)
    return idx.reshape(len(vertices), len(members)), exact


def ball_region(mesh, vertex, radius):
    """The vertices within ``radius`` of ``vertex`` (Euclidean) connected to it inside that ball, sorted.

    Returns
    -------
    vertices : (k,) int numpy array
    """
    radius = opt.positive("radius", radius)
    inside = np.flatnonzero(np.linalg.norm(mesh.V - mesh.V[vertex], axis=1) <= radius)
    G = edge_graph(mesh)[inside][:, inside]
    _, label = csgraph.connected_components(G, directed=False)
    own = label[int(np.flatnonzero(inside == vertex)[0])]
    return np.sort(inside[label == own]).astype(np.int64)


class PlacementRegions:
    """The placement regions of a shape's movable handles, checked, with their correction bumps.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        All handles' nominal vertices.
    moving : (h,) bool numpy array
    movable : (b,) int numpy array
        Indices into ``handles`` of the movable handles (moving handles only), increasing.
    vertices : list of (k_ℓ,) int numpy arrays
        One region per movable handle, holding its nominal vertex.
    reach : (b,) numpy array
        The bump's largest graph distance per region (default :data:`BUMP_REACH` times the region's radius).
    members : list of (s_ℓ,) int numpy arrays, optional
        Per movable handle, its patch: the handles (indices into ``handles``, itself first) that move at rest with
        it by one shared offset (:func:`patch_layout`); default each handle alone (a 2D point handle).

    Attributes
    ----------
    layout : list of (k_ℓ, s_ℓ) int numpy arrays
        Per region, each member's vertex at each region vertex (column 0: the region's vertices).
    moved : (B,) int numpy array
        Every member of every movable patch (indices into ``handles``), region by region.
    """

    def __init__(self, mesh, handles, moving, movable, vertices, reach=None, members=None):
        self.mesh = mesh
        self.handles = np.asarray(handles, np.int64)
        self.moving = np.asarray(moving, bool)
        self.movable = np.asarray(movable, np.int64)
        self.vertices = [region_vertices(ell, v) for ell, v in enumerate(vertices)]
        self.members = check_members(self, members)
        if reach is None:
            reach = [
                BUMP_REACH * max(np.linalg.norm(mesh.V[v] - mesh.V[self.handles[b]], axis=1).max(), 1e-300)
                for b, v in zip(self.movable, self.vertices)
            ]
        self.reach = np.asarray(reach, float)
        if self.reach.shape != (len(self.movable),) or not np.isfinite(self.reach).all() or np.any(self.reach <= 0):
            raise ValueError(
                f"reach must be {len(self.movable)} positive finite lengths (one per movable handle), "
                f"got {np.array2string(self.reach, threshold=10)}"
            )
        self.g = bumps(self)  # (Σ k_ℓ s_ℓ, n_vertices) CSR, rows in region order, members within
        self.offset = np.cumsum([0] + [lay.size for lay in self.layout])
        self.owner = np.full(mesh.n_vertices, -1, np.int64)  # the region of each vertex (-1: none)
        for ell, v in enumerate(self.vertices):
            self.owner[v] = ell

    @property
    def n_movable(self):
        return len(self.movable)

    @property
    def nominal(self):
        """(b,) int numpy array: the movable handles' nominal vertices."""
        return self.handles[self.movable]

    def moving_rows(self):
        """(b,) int numpy array: the movable handles' rows among the moving handles (the rows of Q)."""
        return np.searchsorted(np.flatnonzero(self.moving), self.movable)

    def moved_rows(self):
        """(B,) int numpy array: the rows among the moving handles of every patch member (:attr:`moved`)."""
        return np.searchsorted(np.flatnonzero(self.moving), self.moved)

    def members_at(self, idx):
        """(B,) int numpy array: every patch member's vertex (:attr:`moved`) with the movable handles at ``idx``.

        Raises
        ------
        ValueError
            A vertex of ``idx`` outside its handle's placement region.
        """
        return np.concatenate([lay[pos] for lay, pos in zip(self.layout, self.region_positions(idx))])

    def region_positions(self, idx):
        """(b,) int numpy array: where each vertex of ``idx`` (b,) sits in its handle's :attr:`vertices`.

        Raises
        ------
        ValueError
            A vertex outside its handle's placement region (so that vertices passed directly never get another's).
        """
        idx = np.asarray(idx)
        if idx.shape != (self.n_movable,):
            raise ValueError(f"expected {self.n_movable} region vertices (one per movable handle), got {idx.shape}")
        out = np.empty(len(idx), np.int64)
        for ell, (v, i) in enumerate(zip(self.vertices, idx)):
            pos = int(np.searchsorted(v, i))
            if pos == len(v) or v[pos] != i:
                raise ValueError(
                    f"vertex {int(i)} is not in movable handle {ell}'s placement region ({len(v)} vertices, nominal "
                    f"{int(self.nominal[ell])})"
                )
            out[ell] = pos
        return out

    def resolve(self, P):
        """The vertex (b,) int numpy array of each movable handle's rest position ``P``.

        ``P``: (b,) vertex indices, or (b, d) points that snap to the nearest vertex of their region within
        :data:`SNAP_TOL` times the bounding-box diagonal; None gives the nominal vertices.

        Raises
        ------
        ValueError
            A P of the wrong shape, not finite, off every vertex, or outside its handle's region.
        """
        b, d = self.n_movable, self.mesh.dim
        if P is None:
            return self.nominal.copy()
        if np.iscomplexobj(P):
            raise ValueError("P must be real; got a complex array")
        P = np.asarray(P)
        if P.shape == (b,) and P.dtype.kind in "iu":
            idx = P.astype(np.int64)
        elif P.shape == (b, d) and P.dtype.kind in "fiu":
            P = P.astype(float)
            if not np.isfinite(P).all():
                raise ValueError(f"P has NaN or infinite entries: {np.array2string(P, threshold=20)}")
            idx = np.empty(b, np.int64)
            tol = SNAP_TOL * self.mesh.bbox_diagonal
            for ell, (p, verts) in enumerate(zip(P, self.vertices)):
                dist = np.linalg.norm(self.mesh.V[verts] - p, axis=1)
                if dist.min() > tol:
                    raise ValueError(
                        f"P[{ell}] = {np.array2string(p, precision=6)} is not on a vertex of movable handle {ell}'s "
                        f"placement region ({dist.min():.3g} from the nearest, tolerance {tol:.3g}); use "
                        f"placement.snap(points) to snap a point to its region"
                    )
                idx[ell] = verts[int(np.argmin(dist))]
        else:
            raise ValueError(
                f"P must be ({b},) vertex indices or ({b}, {d}) rest positions of the {b} movable "
                f"handles, got {P.dtype} {P.shape}"
            )
        own = self.owner[np.clip(idx, 0, len(self.owner) - 1)]
        for ell, (v, verts) in enumerate(zip(idx, self.vertices)):
            if own[ell] != ell or v < 0 or v >= len(self.owner):
                raise ValueError(
                    f"P[{ell}] is vertex {int(v)}, outside movable handle {ell}'s placement region "
                    f"({len(verts)} vertices around vertex {int(self.nominal[ell])}){self.whose(v)}"
                )
        return idx

    def whose(self, v):
        """Words naming what else vertex ``v`` is (another region's, a handle's), for an error message."""
        if not 0 <= v < len(self.owner):
            return f": the mesh has {len(self.owner)} vertices"
        h = np.flatnonzero(self.handles == v)
        if len(h):
            return f": it is handle {int(h[0])}'s vertex"
        other = [ell for ell, lay in enumerate(self.layout) if np.isin(v, lay)]
        if other:
            return f": it is in movable handle {other[0]}'s patch region"
        return ""

    def snap(self, points):
        """The nearest vertex of each movable handle's region to ``points`` (b, d): (b,) int numpy array."""
        points = opt.real_array("points", points)
        if points.shape != (self.n_movable, self.mesh.dim) or not np.isfinite(points).all():
            raise ValueError(f"points must be finite, shape ({self.n_movable}, {self.mesh.dim}), got {points.shape}")
        return np.array(
            [v[np.argmin(np.linalg.norm(self.mesh.V[v] - p, axis=1))] for p, v in zip(points, self.vertices)], np.int64
        )

    def bumps_at(self, idx):
        """The bumps of the region vertices ``idx`` (b,) on their joint support: (sup (s,) int, weights (s, B)),
        one column per patch member (:attr:`moved`)."""
        G = self.g[self.bump_rows(idx)].tocsc()
        sup = np.flatnonzero(np.diff(G.indptr))
        return sup, np.ascontiguousarray(G[:, sup].toarray().T)

    def bump_rows(self, idx):
        """Rows of :attr:`g` of the region vertices ``idx`` (b,): (B,), each patch's members in turn."""
        rows = [
            o + pos * lay.shape[1] + np.arange(lay.shape[1])
            for o, pos, lay in zip(self.offset, self.region_positions(idx), self.layout)
        ]
        return np.concatenate(rows)

    def handles_at(self, idx):
        """All handles' vertices (h,) with the movable ones at ``idx`` (b,) and their patches with them."""
        h = self.handles.copy()
        h[self.moved] = self.members_at(idx)
        return h

    def to_arrays(self):
        """{"placement_movable", "placement_vertices", "placement_sizes", "placement_reach"} for a file, and
        {"placement_members", "placement_member_sizes"} when a patch has several members."""
        out = {
            "placement_movable": self.movable,
            "placement_vertices": np.concatenate(self.vertices),
            "placement_sizes": np.array([len(v) for v in self.vertices], np.int64),
            "placement_reach": self.reach,
        }
        if len(self.moved) > len(self.movable):
            out["placement_members"] = self.moved
            out["placement_member_sizes"] = np.array([len(k) for k in self.members], np.int64)
        return out

    @classmethod
    def from_arrays(cls, mesh, handles, moving, arrays):
        """The inverse of :meth:`to_arrays` (checked as on construction)."""
        regions = split_sizes(arrays, "placement_vertices", "placement_sizes")
        members = None
        if "placement_members" in arrays or "placement_member_sizes" in arrays:
            members = split_sizes(arrays, "placement_members", "placement_member_sizes")
        return cls(mesh, handles, moving, arrays["placement_movable"], regions, arrays["placement_reach"], members)


def split_sizes(arrays, flat, sizes):
    """``arrays[flat]`` split into pieces of ``arrays[sizes]`` (positive, summing to its length), int64."""
    if flat not in arrays or sizes not in arrays:
        raise ValueError(f"{flat} and {sizes} come together: one of them is missing")
    n = np.asarray(arrays[sizes], np.int64)
    a = np.asarray(arrays[flat], np.int64)
    if n.ndim != 1 or np.any(n < 1) or n.sum() != len(a):
        raise ValueError(f"{sizes} must be positive and sum to the length of {flat}")
    return np.split(a, np.cumsum(n)[:-1])


def region_vertices(ell, v, what="placement region {} must hold integer vertex indices"):
    """Region ``ell``'s vertices ``v`` as a sorted (k,) int64 array; integral floats pass, fractions do not
    (``what``: the error's words, ``{}`` for ``ell``)."""
    a = np.asarray(v).ravel()
    if a.dtype.kind not in "iuf" or (a.dtype.kind == "f" and not (np.isfinite(a).all() and np.all(a == np.round(a)))):
        raise ValueError(f"{what.format(ell)}, got {a.dtype} {np.array2string(a, threshold=10)}")
    return np.unique(a.astype(np.int64))


def check(pr):
    """Raise ValueError unless the movable handles and regions of ``pr`` are indices of its handles and mesh."""
    n = pr.mesh.n_vertices
    h, mv = pr.handles, pr.movable
    if mv.ndim != 1 or len(mv) == 0 or len(np.unique(mv)) != len(mv) or np.any(np.diff(mv) < 0):
        raise ValueError(f"movable must be increasing, distinct indices into the {len(h)} handles, got {mv}")
    if mv.min() < 0 or mv.max() >= len(h):
        raise ValueError(f"movable indexes {len(h)} handles, got {mv}")
    if not pr.moving[mv].all():
        k = int(mv[~pr.moving[mv]][0])
        raise ValueError(f"handle {k} (vertex {int(h[k])}) is fixed: only moving handles can be movable")
    if len(pr.vertices) != len(mv):
        raise ValueError(f"{len(pr.vertices)} placement regions for {len(mv)} movable handles")
    for ell, (k, v) in enumerate(zip(mv, pr.vertices)):
        if len(v) == 0 or v.min() < 0 or v.max() >= n:
            raise ValueError(f"placement region {ell} must hold vertex indices in [0, {n}), got {len(v)} of them")
        if not np.isin(h[k], v):
            raise ValueError(f"placement region {ell} does not hold its handle's nominal vertex {int(h[k])}")


def check_members(pr, members):
    """The patches of ``pr``'s movable handles (each first in its own), checked: moving handles of one patch
    each, and every region vertex takes its whole patch onto mesh vertices (:func:`patch_layout`). Sets
    ``pr.members``, ``pr.moved`` and ``pr.layout``."""
    check(pr)
    mv = pr.movable
    if members is None:
        members = [[k] for k in mv]
    if len(members) != len(mv):
        raise ValueError(f"members must hold one patch per movable handle ({len(mv)}), got {len(members)}")
    out = []
    for ell, k in enumerate(members):
        k = region_vertices(ell, k, "members[{}] must hold integer handle indices")
        bad = len(k) == 0 or k.min() < 0 or k.max() >= len(pr.handles)
        if bad or not pr.moving[k].all() or not np.isin(mv[ell], k):
            raise ValueError(
                f"members[{ell}] must be moving handles (indices into the {len(pr.handles)} handles) that include "
                f"movable handle {int(mv[ell])}, got {k.tolist()}"
            )
        out.append(patch_first(k, mv[ell]))
    pr.members, pr.moved = out, np.concatenate(out)
    if len(np.unique(pr.moved)) != len(pr.moved):
        raise ValueError(f"a handle is in two movable patches: {[k.tolist() for k in out]}")
    pr.layout = []
    for ell, (k, v) in enumerate(zip(out, pr.vertices)):
        lay, exact = patch_layout(pr.mesh, pr.handles, k, v)
        if not exact.all():
            raise ValueError(
                f"placement region {ell}: at vertex {int(v[~exact][0])} the patch of handles {k.tolist()} would not "
                "sit on mesh vertices (its members move by one shared offset); placement_regions(radius=) keeps "
                "only the vertices where it does"
            )
        pr.layout.append(lay)
    check_disjoint(pr)
    return out


def check_disjoint(pr):
    """Raise ValueError if two patches' regions (every member's vertices) overlap or one holds another handle."""
    n, h = pr.mesh.n_vertices, pr.handles
    owner = np.full(n, -1)
    for ell, lay in enumerate(pr.layout):
        v = np.unique(lay)
        clash = v[owner[v] >= 0]
        if len(clash):
            raise ValueError(
                f"placement regions {int(owner[clash[0]])} and {ell} overlap at vertex {int(clash[0])}"
                " (regions must be disjoint: shrink the radius)"
            )
        owner[v] = ell
    others = np.setdiff1d(np.arange(len(h)), pr.moved)
    inside = others[owner[h[others]] >= 0]
    if len(inside):
        k = int(inside[0])
        kind = "fixed" if not pr.moving[k] else "moving but not movable"
        raise ValueError(
            f"handle {k} ({kind}, vertex {int(h[k])}) lies inside placement region "
            f"{int(owner[h[k]])}: a region may not hold another handle"
        )


def bumps(pr):
    """The correction bumps of every member at every region vertex, (Σ k_ℓ s_ℓ, n_vertices) CSR, rows in region
    order, then region vertex, then member (:meth:`PlacementRegions.bump_rows`).

    g = (1 − (t/ρ)²)² for the edge-graph distance t < ρ from the member's vertex v, 0 beyond; ρ is the region's
    reach, capped at the graph distance to the nearest vertex of another region, of a handle that is not movable or
    of another member at the same placement, so g = 1 at v and 0 there (exactly).
    """
    G = edge_graph(pr.mesh)
    rows, cols, vals = [], [], []
    r0 = 0
    still = np.delete(pr.handles, pr.moved)
    for ell, lay in enumerate(pr.layout):
        blocked = np.concatenate([v.ravel() for j, v in enumerate(pr.layout) if j != ell] + [still]).astype(np.int64)
        k, s = lay.shape
        D = csgraph.dijkstra(G, indices=lay.ravel(), limit=pr.reach[ell])
        for i in range(k * s):
            rho = pr.reach[ell]
            near = np.concatenate([blocked, np.delete(lay[i // s], i % s)])
            if len(near):
                rho = min(rho, float(D[i, near].min()))
            sel = np.flatnonzero(D[i] < rho)
            t = D[i, sel] / rho
            rows.append(np.full(len(sel), r0 + i))
            cols.append(sel)
            vals.append((1.0 - t * t) ** 2)
        r0 += k * s
    g = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, pr.mesh.n_vertices)
    )
    g.sort_indices()
    return g


def placement_regions(shape, movable=None, radius=None, vertices=None, reach=None):
    """The placement regions of ``shape``'s movable handles: balls of ``radius`` or given vertex sets.

    In 3D a movable handle brings its patch (:func:`defop.scene.handles.patches`): the region is where the handle
    itself may sit, and its patch moves with it by one offset (a ball keeps the vertices where every member lands
    on a vertex, :func:`patch_layout`).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    movable : sequence of int, optional
        Indices into ``shape.handles`` (moving handles only, one per patch); default the first handle of every
        patch (in 2D every moving handle).
    radius : float, optional
        Ball radius (a length; e.g. ``0.05 * shape.mesh.bbox_diagonal``): :func:`ball_region` per handle.
    vertices : list of (k_ℓ,) int arrays, optional
        The regions themselves (instead of ``radius``).

    Returns
    -------
    PlacementRegions
    """
    rows = np.flatnonzero(shape.moving)
    groups = [rows[k] for k in patches(shape).members]
    if movable is None:
        mv = np.array([k[0] for k in groups], np.int64)
    else:
        mv = np.array([opt.integer(f"movable[{i}]", k) for i, k in enumerate(np.ravel(movable))], np.int64)
    if (radius is None) == (vertices is None):
        raise ValueError("give exactly one of radius (a ball per movable handle) and vertices (the regions)")
    if mv.size and (mv.min() < 0 or mv.max() >= len(shape.handles)):
        raise ValueError(f"movable indexes {len(shape.handles)} handles, got {mv}")
    members = [next((g for g in groups if k in g), np.array([k])) for k in mv]
    for i, j in zip(*np.triu_indices(len(mv), 1)):
        if mv[j] in members[i]:
            raise ValueError(
                f"handles {int(mv[i])} and {int(mv[j])} are in one patch (they move at rest together): name one"
            )
    if radius is not None:
        radius = opt.positive("radius", radius)
        vertices = []
        for k, g in zip(mv, members):
            ball = ball_region(shape.mesh, shape.handles[k], radius)
            vertices.append(ball[patch_layout(shape.mesh, shape.handles, patch_first(g, k), ball)[1]])
        reach = np.full(len(mv), BUMP_REACH * radius) if reach is None else reach
    return PlacementRegions(shape.mesh, shape.handles, shape.moving, mv, vertices, reach, members)


def patch_first(members, k):
    """The patch ``members`` with handle ``k`` first, the others increasing."""
    members = np.asarray(members, np.int64)
    return np.concatenate([[k], np.sort(members[members != k])]).astype(np.int64)
