"""The page of a :class:`~defop.operator.movable.MovableOp`: handles that move at rest, evaluated in the page.

:func:`movable_to_payload` packs what ``static/defop_movable.js`` needs to evaluate (M) of
:mod:`defop.operator.movable` in JavaScript, with the same formula as the Python frame:

* z(P, Q) = [(P_b − P_b⁰)/s_P, (Q − P)/s_Q] (:func:`~defop.operator.movable.joint_z`), Ψ the TPS basis over the
  joint space (``joint_centers``, kernel r² log r in 2D, r³ in 3D, pseudo-handles at 0, scale 1: the evaluator of
  DefOp's page, ``makePsi``), δψ(P, Q) = Ψ(z(P, Q))[1:] − Ψ(z(P, P))[1:];
* u = δψ A B (the float32 factors, products accumulated in float64), X = x + u;
* the residual correction Σ_ℓ g_{v_ℓ} r_ℓ (the placement's bumps, CSR rows ``bump_*`` in region order), then the
  moving handles written as Q, the fixed ones as x, and a frame with Q = P returns x bit for bit (8b)
  (:func:`~defop.operator.movable.correct`).

The page (:func:`defop.editor.export.to_html` with a MovableOp) is the 2D editor, or the 3D view
(``static/defop_solid.js``), with a rest mode: a toggle (or Shift-drag) moves a movable handle's rest position
within its placement region, drawn on the mesh (in 3D its vertices as points, inside the shape too), snapping to the
region's vertices; a bad placement (outside the region, onto another handle) is refused with a visible message and
nothing changes. In 3D a movable handle is a patch (:attr:`defop.scene.placement.PlacementRegions.members`): the
page moves every member by the handle's rest offset (``layout``), as Python does, and the dimension is the
payload's ``d`` (one evaluator, ``makeMovable``, for both).
"""

from __future__ import annotations

import re

import numpy as np

from .compact import drawn_vertices, vertex_renumbering
from .logic import reach_polygons
from .payload import JS_PATH, mesh_edges, script_after_editor

MOVABLE_JS_PATH = JS_PATH.with_name("defop_movable.js")

#: the page's instruction line (replaces the fixed-P page's), by dimension
INSTRUCTION = {
    2: "Drag a red handle with the mouse: the shape follows, computed in this page. Shift-drag a handle (or turn on "
    "&quot;move rest handle&quot;) to move its rest position within its placement region (green).",
    3: "Drag a red handle in the view plane; drag elsewhere to orbit, scroll to zoom. Shift-drag a red handle among "
    "green points (or turn on &quot;move rest handle&quot;) to move its rest position to one of its placement "
    "region's vertices (green): the handles of its patch move with it by the same offset.",
}


def movable_to_payload(op, regions=None, factors=None):
    """Everything the page needs to evaluate and draw a MovableOp (2D or 3D) at its nominal placement.

    Parameters
    ----------
    op : defop.operator.movable.MovableOp
        The compressed factors (A, B) when present (as shipped, float32), otherwise W_F in float32.
    regions : list of list of (k,2) numpy array, optional
        2D: sampling-region polygons of the moving handles around their nominal rest positions; default discs of
        the operator's reach (the farthest training offset). The page translates a handle's polygons with its rest
        position. 3D: balls ``[cx, cy, cz, r]`` (:func:`defop.editor.payload.region_balls`; default none: the 3D
        page draws the placement regions' vertices, not the sampling balls).
    factors : tuple of two numpy arrays, optional
        (A, B) to ship instead of ``op.factors`` (the standalone page's: :func:`defop.editor.payload.page_factors`,
        B on its grid, as the fixed-P page's).

    Returns
    -------
    payload : dict
        ``movable`` 1 and the keys of :func:`defop.editor.payload.defop_to_payload` that the editor draws (``d``,
        ``kind``, ``size``, ``n_moving``, ``n_vertices``, ``regions``, ``P``, ``V``, ``F`` (in 3D the boundary
        facets), ``E`` (2D), ``handles``, ``moving``, ``A``, ``B``, ``rank``), plus the joint basis (``kernel``,
        ``joint_centers`` (|C|, (b + n) d)), the scales ``s_p``, ``s_q``, the placement (``placement_movable``
        indices into the handles, ``movable_rows`` their rows of Q, ``nominal`` vertices, ``region_vertices`` and
        ``region_sizes``), the patches (:attr:`~defop.scene.placement.PlacementRegions.members`: ``members`` (B,)
        every member's handle, ``member_rows`` its row of Q, ``member_sizes`` (b,), ``layout`` every region's
        (k_ℓ, s_ℓ) member vertices, flat; in 2D every patch is its handle alone) and the bumps ``bump_indptr``,
        ``bump_indices``, ``bump_data`` (CSR, one row per member per region vertex, in region order).
    """
    pl, basis, d = op.placement, op.basis, op.d
    P = op.mesh.V[op.handles[op.moving]]
    if regions is None and d == 2:
        reach = None if op.reach is None else (P + op.reach[:, None] * [1.0, 0.0])[None]  # (1, n, 2) at the reach
        regions = reach_polygons(P, reach)
    elif regions is None:
        regions = [[] for _ in P]
    g = pl.g.tocsr()
    F = np.asarray(op.mesh.F if d == 2 else op.mesh.boundary_facets)
    p = {
        "movable": 1,
        "d": int(d),
        "kind": "tps",
        "kernel": basis.kernel,
        "size": int(basis.size),
        "n_moving": int(op.n_moving),
        "n_vertices": int(op.n_vertices),
        "regions": [[np.asarray(poly, float).ravel().tolist() for poly in polys] for polys in regions],
        "P": np.asarray(P, np.float64),
        "V": np.asarray(op.mesh.V, np.float64),
        "F": F.astype(np.int32),
        "handles": np.asarray(op.handles, np.int32),
        "moving": np.asarray(op.moving, np.uint8),
        "joint_centers": np.asarray(basis.centers, np.float64).reshape(len(basis.centers), -1),
        "s_p": float(op.scales[0]),
        "s_q": float(op.scales[1]),
        "placement_movable": np.asarray(pl.movable, np.int32),
        "movable_rows": np.asarray(pl.moving_rows(), np.int32),
        "nominal": np.asarray(pl.nominal, np.int32),
        "region_vertices": np.concatenate(pl.vertices).astype(np.int32),
        "region_sizes": np.array([len(v) for v in pl.vertices], np.int32),
        "members": np.asarray(pl.moved, np.int32),
        "member_rows": np.asarray(pl.moved_rows(), np.int32),
        "member_sizes": np.array([len(k) for k in pl.members], np.int32),
        "layout": np.concatenate([lay.ravel() for lay in pl.layout]).astype(np.int32),
        "bump_indptr": np.asarray(g.indptr, np.int32),
        "bump_indices": np.asarray(g.indices, np.int32),
        "bump_data": np.asarray(g.data, np.float64),
    }
    if d == 2:
        p["E"] = mesh_edges(F).astype(np.int32)
    factors = op.factors if factors is None else factors
    if factors is not None:
        p["A"], p["B"] = (np.asarray(f, np.float32) for f in factors)
        p["rank"] = int(p["A"].shape[1])
    else:
        p["A"] = np.asarray(op.WF, np.float32)
    return p


def drawn_payload(p):
    """A 3D movable payload restricted to the vertices the page draws and those its placement uses (every member's
    vertex at every region vertex: ``layout``), as the fixed-P 3D page (:func:`defop.editor.compact.drawn_vertices`),
    a new dict. The bumps keep their entries on kept vertices (an entry elsewhere changes only a vertex the page
    does not evaluate), so every kept vertex is evaluated as before; ``drawn`` maps the page's vertices to the
    operator's (the page speaks the operator's vertex indices: ``makeMovable``'s setRest and placement).

    Returns
    -------
    dict
    """
    out = drawn_vertices(p, also=p["layout"], renumbered=("nominal", "region_vertices", "layout"))
    if "drawn" not in out:
        return out
    renumber = vertex_renumbering(out["drawn"], out["n_vertices_all"])
    kept = renumber[p["bump_indices"]] >= 0
    out["bump_indptr"] = np.concatenate([[0], np.cumsum(kept)])[p["bump_indptr"]].astype(np.int32)
    out["bump_indices"] = renumber[p["bump_indices"][kept]]
    out["bump_data"] = p["bump_data"][kept]
    return out


def movable_script():
    """The movable page's inline module: ``defop_editor.js`` verbatim, then ``defop_movable.js`` without its import
    line (the names it imports are in the same module scope), as :func:`defop.editor.export.solid_script` does.

    Returns
    -------
    str
    """
    return JS_PATH.read_text(encoding="utf-8") + "\n" + script_after_editor(MOVABLE_JS_PATH)


#: the page's legend entry of the placement regions (added before the fixed-P page's entries), by dimension
LEGEND = {
    2: '<span><i class="defop-swatch" style="background:rgba(44,160,44,0.25);border:1px solid #2ca02c"></i>placement '
    "region of a rest handle (its green vertices: where its rest position may go)</span>\n",
    3: '<span><i class="defop-swatch" style="border-radius:50%;background:#2ca02c"></i>placement region of a rest '
    "handle (its green vertices, inside the shape too: where its rest position may go)</span>\n",
}


def movable_page(template, d=2):
    """The 2D page's template (or the 3D page's, ``d`` = 3) with the movable instruction and legend entry, and in 2D
    ``mountMovable`` instead of ``mountStandalone`` (the 3D page's ``mountSolid`` takes a movable payload)."""
    legend = '<div class="defop-legend" aria-label="legend">\n'
    if legend not in template:
        raise RuntimeError("the page's template has no legend to add the placement regions to")
    template = template.replace(legend, legend + LEGEND[d], 1)
    out = re.sub(
        r'<p class="defop-instruction">[^<]*</p>',
        f'<p class="defop-instruction">{INSTRUCTION[d]}</p>',
        template,
        count=1,
    )
    return out.replace("mountStandalone(", "mountMovable(")
