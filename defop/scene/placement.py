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

Each region vertex v carries a correction bump g_v (:func:`bumps`): 1 at v, 0 at every vertex of the other
regions and at every handle that is not movable, a smooth function of the mesh's edge-graph distance in between.
The movable operator (:mod:`defop.operator.movable`) spreads each handle's residual with it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from .. import options as opt

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
    """

    def __init__(self, mesh, handles, moving, movable, vertices, reach=None):
        self.mesh = mesh
        self.handles = np.asarray(handles, np.int64)
        self.moving = np.asarray(moving, bool)
        self.movable = np.asarray(movable, np.int64)
        self.vertices = [region_vertices(ell, v) for ell, v in enumerate(vertices)]
        check(self)
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
        self.g = bumps(self)  # (Σ k_ℓ, n_vertices) CSR, rows in region order
        self.offset = np.cumsum([0] + [len(v) for v in self.vertices])
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
                    f"({len(verts)} vertices around vertex {int(self.nominal[ell])})"
                )
        return idx

    def snap(self, points):
        """The nearest vertex of each movable handle's region to ``points`` (b, d): (b,) int numpy array."""
        points = opt.real_array("points", points)
        if points.shape != (self.n_movable, self.mesh.dim) or not np.isfinite(points).all():
            raise ValueError(f"points must be finite, shape ({self.n_movable}, {self.mesh.dim}), got {points.shape}")
        return np.array(
            [v[np.argmin(np.linalg.norm(self.mesh.V[v] - p, axis=1))] for p, v in zip(points, self.vertices)], np.int64
        )

    def bumps_at(self, idx):
        """The bumps of the region vertices ``idx`` (b,) on their joint support: (sup (s,) int, weights (s, b))."""
        G = self.g[self.bump_rows(idx)].tocsc()
        sup = np.flatnonzero(np.diff(G.indptr))
        return sup, np.ascontiguousarray(G[:, sup].toarray().T)

    def bump_rows(self, idx):
        """Rows of :attr:`g` of the region vertices ``idx`` (b,)."""
        return np.array([o + int(np.searchsorted(v, i)) for o, v, i in zip(self.offset, self.vertices, idx)])

    def handles_at(self, idx):
        """All handles' vertices (h,) with the movable ones at ``idx`` (b,)."""
        h = self.handles.copy()
        h[self.movable] = idx
        return h

    def to_arrays(self):
        """{"placement_movable", "placement_vertices", "placement_sizes", "placement_reach"} for a file."""
        return {
            "placement_movable": self.movable,
            "placement_vertices": np.concatenate(self.vertices),
            "placement_sizes": np.array([len(v) for v in self.vertices], np.int64),
            "placement_reach": self.reach,
        }

    @classmethod
    def from_arrays(cls, mesh, handles, moving, arrays):
        """The inverse of :meth:`to_arrays` (checked as on construction)."""
        sizes = np.asarray(arrays["placement_sizes"], np.int64)
        flat = np.asarray(arrays["placement_vertices"], np.int64)
        if sizes.ndim != 1 or np.any(sizes < 1) or sizes.sum() != len(flat):
            raise ValueError("placement_sizes must be positive and sum to the length of placement_vertices")
        return cls(
            mesh,
            handles,
            moving,
            arrays["placement_movable"],
            np.split(flat, np.cumsum(sizes)[:-1]),
            arrays["placement_reach"],
        )


def region_vertices(ell, v):
    """Region ``ell``'s vertices ``v`` as a sorted (k,) int64 array; integral floats pass, fractions do not."""
    a = np.asarray(v).ravel()
    if a.dtype.kind not in "iuf" or (a.dtype.kind == "f" and not (np.isfinite(a).all() and np.all(a == np.round(a)))):
        raise ValueError(
            f"placement region {ell} must hold integer vertex indices, got {a.dtype} {np.array2string(a, threshold=10)}"
        )
    return np.unique(a.astype(np.int64))


def check(pr):
    """Raise ValueError unless the regions of ``pr`` follow the module's rules."""
    n = pr.mesh.n_vertices
    h, mv = pr.handles, pr.movable
    if pr.mesh.dim != 2:
        raise ValueError(
            "placement regions (movable rest handles) are implemented on triangle meshes only, not on this "
            f"{pr.mesh.dim}D mesh: a tetrahedral handle is a patch of vertices (bar_3d's end is 4) that would have "
            "to move at rest together, by one shared offset, which one placement region per handle vertex does "
            "not express, and the joint training was not validated in 3D"
        )
    if mv.ndim != 1 or len(mv) == 0 or len(np.unique(mv)) != len(mv) or np.any(np.diff(mv) < 0):
        raise ValueError(f"movable must be increasing, distinct indices into the {len(h)} handles, got {mv}")
    if mv.min() < 0 or mv.max() >= len(h):
        raise ValueError(f"movable indexes {len(h)} handles, got {mv}")
    if not pr.moving[mv].all():
        k = int(mv[~pr.moving[mv]][0])
        raise ValueError(f"handle {k} (vertex {int(h[k])}) is fixed: only moving handles can be movable")
    if len(pr.vertices) != len(mv):
        raise ValueError(f"{len(pr.vertices)} placement regions for {len(mv)} movable handles")
    owner = np.full(n, -1)
    for ell, (k, v) in enumerate(zip(mv, pr.vertices)):
        if len(v) == 0 or v.min() < 0 or v.max() >= n:
            raise ValueError(f"placement region {ell} must hold vertex indices in [0, {n}), got {len(v)} of them")
        if not np.isin(h[k], v):
            raise ValueError(f"placement region {ell} does not hold its handle's nominal vertex {int(h[k])}")
        clash = v[owner[v] >= 0]
        if len(clash):
            raise ValueError(
                f"placement regions {int(owner[clash[0]])} and {ell} overlap at vertex {int(clash[0])}"
                " (regions must be disjoint: shrink the radius)"
            )
        owner[v] = ell
    others = np.setdiff1d(np.arange(len(h)), mv)
    inside = others[owner[h[others]] >= 0]
    if len(inside):
        k = int(inside[0])
        kind = "fixed" if not pr.moving[k] else "moving but not movable"
        raise ValueError(
            f"handle {k} ({kind}, vertex {int(h[k])}) lies inside placement region "
            f"{int(owner[h[k]])}: a region may not hold another handle"
        )


def bumps(pr):
    """The correction bumps g_v of every region vertex, (Σ k_ℓ, n_vertices) CSR, rows in region order.

    g_v = (1 − (t/ρ_v)²)² for the edge-graph distance t < ρ_v from v, 0 beyond; ρ_v is the region's reach,
    capped at the graph distance to the nearest vertex of another region or handle that is not movable, so
    g_v = 1 at v and 0 there (exactly).
    """
    G = edge_graph(pr.mesh)
    rows, cols, vals = [], [], []
    r0 = 0
    for ell, verts in enumerate(pr.vertices):
        blocked = np.concatenate(
            [v for j, v in enumerate(pr.vertices) if j != ell] + [np.delete(pr.handles, pr.movable)]
        ).astype(np.int64)
        D = csgraph.dijkstra(G, indices=verts, limit=pr.reach[ell])
        for i in range(len(verts)):
            rho = pr.reach[ell]
            if len(blocked):
                rho = min(rho, float(D[i, blocked].min()))
            sel = np.flatnonzero(D[i] < rho)
            t = D[i, sel] / rho
            rows.append(np.full(len(sel), r0 + i))
            cols.append(sel)
            vals.append((1.0 - t * t) ** 2)
        r0 += len(verts)
    g = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, pr.mesh.n_vertices)
    )
    g.sort_indices()
    return g


def placement_regions(shape, movable=None, radius=None, vertices=None, reach=None):
    """The placement regions of ``shape``'s movable handles: balls of ``radius`` or given vertex sets.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    movable : sequence of int, optional
        Indices into ``shape.handles`` (moving handles only); default every moving handle.
    radius : float, optional
        Ball radius (a length; e.g. ``0.05 * shape.mesh.bbox_diagonal``): :func:`ball_region` per handle.
    vertices : list of (k_ℓ,) int arrays, optional
        The regions themselves (instead of ``radius``).

    Returns
    -------
    PlacementRegions
    """
    if movable is None:
        mv = np.flatnonzero(shape.moving)
    else:
        mv = np.array([opt.integer(f"movable[{i}]", k) for i, k in enumerate(np.ravel(movable))], np.int64)
    if (radius is None) == (vertices is None):
        raise ValueError("give exactly one of radius (a ball per movable handle) and vertices (the regions)")
    if radius is not None:
        radius = opt.positive("radius", radius)
        if mv.size and (mv.min() < 0 or mv.max() >= len(shape.handles)):
            raise ValueError(f"movable indexes {len(shape.handles)} handles, got {mv}")
        vertices = [ball_region(shape.mesh, shape.handles[k], radius) for k in mv]
        reach = np.full(len(mv), BUMP_REACH * radius) if reach is None else reach
    return PlacementRegions(shape.mesh, shape.handles, shape.moving, mv, vertices, reach)
