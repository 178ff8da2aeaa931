"""The editor's rest mode: moving a movable handle's rest position P within its placement region.

With a :class:`~defop.operator.movable.MovableOp` the editor's state (:class:`defop.editor.state.EditorState`,
whose methods call these functions) keeps the placement ``rest`` (b,) of its movable handles. A toggle
(:func:`set_rest_mode`) or a Shift-press makes a pointer move a rest handle instead of a moving one: the
press picks a movable handle, the drag shows the region vertex it would snap to, the release places it there
(:func:`set_rest`; from code, a vertex or a point). While deformed, q − p stays
(:func:`defop.operator.movable.retarget`). The same mode as the page's (``static/defop_movable.js``), with the same
rules: a place outside the handle's region or onto another handle is refused (a ValueError naming the handle and
the vertex) and nothing changes.
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from ..operator.movable import retarget
from ..training.movable import shape_at
from .logic import STATE, check_flag, check_index, region_polygons, restoring


def rest_vertex(placement, handles, X, ell, target, snap):
    """The vertex for movable handle ``ell``'s rest position, or a ValueError saying why there is none.

    Parameters
    ----------
    placement : defop.scene.placement.PlacementRegions
    handles : (h,) int numpy array
        Every handle's current vertex (the movable ones at the current placement).
    X : (n_vertices, 2) numpy array
        The current deformation: a point is snapped where the user sees the mesh.
    ell : int
        The movable handle (0..b−1).
    target : int or (2,) array-like
        A vertex index, or a point that snaps to the nearest vertex of the region within ``snap``.
    snap : float
        The snapping distance (mesh units).

    Returns
    -------
    int
    """
    region, movable = placement.vertices[ell], int(placement.movable[ell])
    others = [h for h in range(len(handles)) if h != movable]
    if isinstance(target, (int, np.integer)) and not isinstance(target, bool):
        v = int(target)
        onto = [h for h in others if handles[h] == v]
        if onto:
            raise ValueError(f"rest handle {ell} cannot move onto vertex {v}: it holds handle {onto[0]}")
        if v not in region:
            raise ValueError(
                f"vertex {v} is outside rest handle {ell}'s placement region ({len(region)} vertices around vertex "
                f"{int(placement.nominal[ell])})"
            )
        return v
    p = opt.point("target", target)
    dist = np.linalg.norm(X[region] - p, axis=1)
    k = int(np.argmin(dist))
    near = np.linalg.norm(X[handles[others]] - p, axis=1) if others else np.zeros(0)
    for h, dh in zip(others, near):
        if dh <= snap and dh < dist[k]:
            raise ValueError(f"rest handle {ell} cannot move onto handle {h} (vertex {int(handles[h])})")
    if dist[k] > snap:
        raise ValueError(
            f"({p[0]:.4g}, {p[1]:.4g}) is outside rest handle {ell}'s placement region: the nearest of its vertices "
            f"is {dist[k]:.3g} away, more than the snapping distance {snap:.3g}"
        )
    return int(region[k])


def init_rest(state):
    """Read the placement of ``state``'s operator (the nominal rest) and switch the mode off: the attributes
    ``placement`` (:class:`~defop.scene.placement.PlacementRegions` or None), ``rest`` ((b,) int numpy array of the
    movable handles' vertices, None when the operator is not movable), ``rest_mode`` (the toggle), ``rest_active``
    (the rest handle being dragged) and ``rest_target`` (the vertex the drag would place it at, None where refused).
    """
    state.placement = getattr(state.operator, "placement", None)
    if state.placement is not None and len(state.kinds) > 1:
        raise ValueError(f"a MovableOp is the editor's one operator: pass kinds=('{state.kind}',), got {state.kinds}")
    state.base_shape = state.shape
    state.rest = None if state.placement is None else state.placement.nominal.copy()
    state.rest_mode, state.rest_active, state.rest_target = False, None, None


def frame(state, Q=None):
    """D(·; P, Q) at ``state``'s placement (D(·, Q) for a fixed-P operator); Q default the current one."""
    Q = state.Q if Q is None else Q
    return state.operator(Q) if state.rest is None else state.operator(Q, state.rest)


def set_rest_mode(state, enabled):
    """Turn the rest mode on (a press moves a rest handle) or off; refused without a MovableOp."""
    enabled = check_flag("enabled", enabled)
    if enabled and state.rest is None:
        raise ValueError("the rest mode needs a MovableOp (handles that move at rest); this operator is fixed-P")
    state.rest_mode = enabled


def set_rest(state, ell, target):
    """Move movable handle ``ell``'s rest position to ``target`` (a vertex of its region, or a point that snaps to
    the nearest one within ``pick_radius`` of the diagonal, in the deformed mesh) and re-evaluate.

    Raises
    ------
    ValueError
        No MovableOp, a bad index, a place outside the region or onto another handle: nothing changes.
    """
    if state.rest is None:
        raise ValueError("set_rest needs a MovableOp (handles that move at rest); this operator is fixed-P")
    ell = check_index(ell, len(state.rest))
    handles = state.placement.handles_at(state.rest)
    v = rest_vertex(state.placement, handles, state.X, ell, target, state.pick_radius * state.diag)
    idx = state.rest.copy()
    idx[ell] = v
    with restoring(state, STATE):
        Q = retarget(state.Q, state.placement, state.rest, idx)
        state.rest, state.shape = idx, shape_at(state.base_shape, state.placement, idx)
        state.P = np.array(state.shape.P_moving, dtype=float)
        state.regions = region_polygons(state.P, state.shape.regions)
        state._solver = None  # the ground truth's handles moved with the rest
        state.X_gt = state.Q_gt = state.gt_result = state.gt_error = None
        state.set_Q(Q)


def press_rest(state, x, y):
    """Start dragging the rest handle nearest to (x, y) (the deformed mesh); its index, or None."""
    x, y = opt.point("(x, y)", (x, y))
    at = state.X[state.placement.handles_at(state.rest)[state.placement.movable]]
    d = np.hypot(at[:, 0] - x, at[:, 1] - y)
    i = int(np.argmin(d))
    state.rest_active = i if d[i] <= state.pick_radius * state.diag else None
    state.rest_target = None if state.rest_active is None else int(state.rest[i])
    return state.rest_active


def drag_rest(state, x, y):
    """The vertex the dragged rest handle would snap to at (x, y), or None where it would be refused."""
    xy = opt.point("(x, y)", (x, y))
    handles = state.placement.handles_at(state.rest)
    try:
        snap = state.pick_radius * state.diag
        state.rest_target = rest_vertex(state.placement, handles, state.X, state.rest_active, xy, snap)
    except ValueError:
        state.rest_target = None
    return state.rest_target


def release_rest(state, xy=None):
    """End the rest drag at point ``xy`` (default: the target the drag showed): :func:`set_rest` there (a
    ValueError when refused, and nothing changes but the end of the drag)."""
    ell, target = state.rest_active, state.rest_target
    state.rest_active, state.rest_target = None, None
    if xy is None and target is None:
        raise ValueError(f"rest handle {ell} has no place under the pointer (outside its region): it stays")
    set_rest(state, ell, target if xy is None else opt.point("(x, y)", xy))
    return True
