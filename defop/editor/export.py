"""The standalone page: one self-contained HTML file that drags a DefOp offline (no Python, no network)."""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re

from .. import options as opt
from ..operator.branched import BranchedOperator
from ..operator.core import EXTRAPOLATION_FACTOR
from ..operator.defop import DefOp, check_mesh
from ..operator.movable import MovableOp
from ..scene.planar_shapes import image_frame as image_frame_of
from ..scene.shapes import Shape
from .compact import compact_payload
from .movable_page import MOVABLE_JS_PATH, drawn_payload, movable_page, movable_script, movable_to_payload
from .payload import (
    JS_PATH,
    branched_to_payload,
    check_compress,
    defop_to_payload,
    encode_payload,
    image_for,
    page_factors,
    region_balls,
    script_after_editor,
    surface_payload,
)
from .state import region_polygons

SOLID_JS_PATH = JS_PATH.with_name("defop_solid.js")
THREE_DIR = JS_PATH.with_name("three")
THREE_VERSION = "0.170.0"
#: the vendored three.js bundle (static/three/README.md: the names the page uses, OrbitControls among them): name ->
#: sha256, checked before a page inlines it
THREE_FILES = {"three.defop.min.js": "0f878d9f5adb24b0d020c699c13aae5955cd9bd8729d86787c0ff8ae90e28142"}

# the head of both pages: a strict Content-Security-Policy (inline script and style only: nothing is fetched)
_HEAD = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<meta http-equiv="Content-Security-Policy"
 content="default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'">
<style>
body {{ margin: 12px; font: 13px system-ui, sans-serif; color: #222; }}
h1 {{ font-size: 18px; margin: 0 0 2px; }}
.defop-instruction {{ margin: 0 0 8px; }}
.defop-legend {{ display: flex; flex-wrap: wrap; gap: 4px 16px; margin: 8px 0; font-size: 12px; color: #333; }}
.defop-legend span {{ display: inline-flex; align-items: center; gap: 5px; }}
.defop-swatch {{ display: inline-block; width: 12px; height: 12px; box-sizing: border-box; }}
.defop-note {{ font-size: 12px; color: #555; }}
</style>
</head><body>
<h1>{title}</h1>
"""
_PAGE = (
    _HEAD
    + """\
<p class="defop-instruction">Drag a red handle with the mouse: the shape follows, computed in this page.</p>
<div id="defop-app"></div>
<div class="defop-legend" aria-label="legend">
<span><i class="defop-swatch" style="border-radius:50%;background:#d62728;border:1px solid #000"></i>moving handle
(drag it)</span>
<span><i class="defop-swatch" style="border-radius:50%;background:#1f77b4;border:1px solid #000"></i>fixed
handle</span>
<span><i class="defop-swatch" style="background:rgba(255,127,14,0.10);border:1px solid rgba(255,127,14,0.7)"></i>
sampling region of a handle (a disc around it, its Voronoi cell, or both): the positions it was trained on</span>
<span><i class="defop-swatch" style="border-radius:50%;border:2px solid #b00"></i>handle beyond {factor:g}&times;
its farthest training sample: the operator extrapolates</span>
<span><i class="defop-swatch" style="background:#e04040"></i>flipped triangle</span>
</div>
<p class="defop-note">D(x, Q) = &Sigma;<sub>ij</sub> C<sub>ij</sub> &phi;<sub>i</sub>(x) &psi;<sub>j</sub>(Q)
(Eq. 3 of Poranne &amp; Lipman) is evaluated in this page, with no network access; written by defop.</p>
<script type="module">
{js}
window.defopEditor = mountStandalone(document.getElementById("defop-app"), {meta}, "{data}");
</script>
</body></html>
"""
)

# the multi-valued page (a BranchedOperator): the 2D page with what the branch readout and the toggle mean
_PAGE_BRANCHED = _PAGE.replace(
    '<p class="defop-instruction">Drag a red handle with the mouse: the shape follows, computed in this page.</p>',
    '<p class="defop-instruction">Drag a red handle across the jump and back: the shape stays on its branch while '
    "that branch exists (follow), so it jumps at different places on the way out and on the way back.</p>",
).replace(
    '<p class="defop-note">',
    '<p class="defop-note">One closed-form operator per branch of D<sup>E</sup>; a branch exists where its '
    "estimated stability margin &lambda;&sup2;<sub>b</sub>(Q) is positive and Q is on its side of the mode score "
    "(defop.operator.branched). Follow stays on the current branch while it exists, else takes the existing branch "
    "of lowest estimated energy E<sub>b</sub>(Q); global always takes the lowest; Reset goes back to the rest "
    'pose\'s branch.</p>\n<p class="defop-note">',
)

_PAGE_3D = (
    _HEAD
    + """\
<p class="defop-instruction">Drag a red handle in the view plane; drag elsewhere to orbit, scroll to zoom.</p>
<div id="defop-app"></div>
<div class="defop-legend" aria-label="legend">
<span><i class="defop-swatch" style="border-radius:50%;background:#d62728"></i>moving handle (drag it)</span>
<span><i class="defop-swatch" style="border-radius:50%;background:#1f77b4"></i>fixed handle</span>
<span><i class="defop-swatch" style="border-radius:50%;background:#4a0000"></i>handle beyond {factor:g}&times; its
farthest training sample: the operator extrapolates</span>
<span><i class="defop-swatch" style="background:#f2d7a6;border:1px solid #999"></i>{surface_legend}</span>
</div>
<p class="defop-note">D(x, Q) = &Sigma;<sub>ij</sub> C<sub>ij</sub> &phi;<sub>i</sub>(x) &psi;<sub>j</sub>(Q)
(Eq. 3 of Poranne &amp; Lipman) is evaluated in this page for every vertex of the tetrahedral mesh the drawn
surface uses, with no network access; handles exact (Prop. 2), rest pose exact (8b). Drawn with three.js
{three_version} (MIT licence, Copyright 2010-2024 three.js authors); written by defop.</p>
<script type="module">
{js}
window.defopEditor = mountSolid(document.getElementById("defop-app"), {meta}, "{data}", THREE, OrbitControls);
</script>
</body></html>
"""
)


def _check_dimensions(op, shape, image, image_frame):
    """A 3D operator with a 2D shape (or the reverse), or a picture on a 3D mesh: a ValueError naming them."""
    if shape is not None and shape.mesh.dim != op.d:
        raise ValueError(
            f"shape must be a {op.d}D shape for this {op.d}D operator, got the {shape.mesh.dim}D shape "
            f"{shape.name!r} ({'tetrahedra' if shape.mesh.dim == 3 else 'triangles'})"
        )
    if op.d == 3 and (image is not None or image_frame is not None):
        raise ValueError("image and image_frame are for 2D operators (a picture on the triangles); this operator is 3D")


def _frame(image, image_frame, shape):
    """``image_frame``, or found from the picture and the shape ``from_image`` made of it."""
    if image is None or image_frame is not None:
        return image_frame
    if shape is None:
        raise ValueError(
            "image= needs shape= (the Shape dop.shapes.from_image made from this picture: the page finds where the "
            "mesh lies in the picture from its outline), or image_frame= (the rest vertices in pixels)"
        )
    return image_frame_of(image, shape)


def to_html(op, path, shape=None, title=None, image=None, image_frame=None, compress=True):
    """Write one self-contained page that drags ``op`` offline (inline script, no network access).

    A 2D operator gets the 2D editor (``static/defop_editor.js``). A 3D operator (tetrahedra) gets the 3D view
    (``static/defop_solid.js`` with the vendored three.js): the surface shaded smoothly, an orbit camera,
    handles as spheres dragged in the view plane, a reset button; the page evaluates the operator with the
    same evaluator (``makeOperator`` of ``defop_editor.js``) for every vertex, then the shape's own surface
    (``shape.surface``, :class:`~defop.geometry.volumetric.surface.EmbeddedSurface`, :func:`.payload.surface_payload`)
    from its barycentric coordinates in the tetrahedra, or without one the boundary facets of the tetrahedra.
    Without WebGL the 3D page says so in words.

    By default the page carries the compressed operator (``compress=True``): the float32 factors W_F ≈ A B of
    :meth:`DefOp.compress <defop.operator.defop.DefOp.compress>` at its default tolerance (``op``'s own factors if
    it has them), B rounded to a power-of-two grid per row that shares its error equally between the rows and
    Rice-coded (:func:`.payload.page_factors`, :mod:`.compact`), computed for the page (``op`` itself is
    unchanged); a 3D page evaluates only the vertices its surface uses. The handles stay exact (Prop. 2) and the
    rest pose exact (8b): B is zero on the handle columns and A multiplies δψ(P) = 0; the rest of the shape moves
    within the compression's tolerance of ``op``. The default octopus page (3,910 vertices, TPS of 200 samples,
    rank 67) is 0.95 MB instead of 9.6 MB; octopus_3d at rank 105 (5,424 of its 10,327 vertices drawn) 2.8 MB.
    ``compress=False`` ships the full W_F (in float32). The page also carries the operators' extrapolation rule
    (:data:`~defop.operator.core.EXTRAPOLATION_FACTOR` times each handle's farthest training sample,
    :func:`.payload.extrapolation_payload`): it warns where Python does.

    Parameters
    ----------
    op : defop.operator.DefOp, defop.operator.branched.BranchedOperator or defop.operator.movable.MovableOp
        A MovableOp gets the page with its rest mode (:func:`movable_html`, 2D or 3D): a toggle or
        Shift-drag moves a rest handle (in 3D its patch) within its placement region.
        A 2D BranchedOperator gets the 2D page with every branch (:func:`.payload.branched_to_payload`): the drag
        runs ``follow`` (``makeBranched`` of ``defop_editor.js``), a toggle switches to ``global``, the current
        branch's label is shown, and Reset goes back to branch 0 (the rest pose's).
    path : str or pathlib.Path
    shape : defop.scene.shapes.Shape, optional
        Its sampling regions are drawn (default: discs, balls in 3D, through the farthest training sample of
        each handle), and in 3D its ``surface`` is the one drawn. Its mesh must be the operator's (same
        dimension too).
    title : str, optional
        Any string: it is shown as text (HTML-escaped in ``<title>``, JSON-escaped in the inline script, where
        ``<``, ``>`` and ``&`` become ``\\u003c``, ``\\u003e``, ``\\u0026`` so no ``</script>`` or ``<!--`` can end
        or break the script). A lone surrogate becomes U+FFFD.
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path, optional
        A picture drawn on the deformed mesh, inlined as a PNG (grey, RGB or RGBA; bool, integer or float in
        [0,1]; at most 4096 pixels a side). For a shape made by ``dop.shapes.from_image(picture)`` this is all:
        the page places the picture itself, by finding its silhouette again and matching it to ``shape``'s
        outline (:func:`defop.scene.planar_shapes.image_frame`), so ``shape`` is needed.
    image_frame : callable or (n_vertices,2) numpy array, optional
        Where the mesh lies in the picture, instead: ``to_pixels((k,2) mesh coordinates) -> (k,2) pixels``, or the
        rest vertices in pixels (x = column, y = row down, pixel centres at integers). Needed when ``from_image``
        was given ``threshold=`` or ``foreground=`` (``dop.shapes.image_frame(picture, shape, threshold=...)``),
        or when the picture is not the one the shape was made from.
    compress : bool
        True (default): the compressed factors of a :class:`DefOp` or a MovableOp (:func:`.payload.page_factors`);
        False: the full W_F (a MovableOp's own factors as they are, if it has them). A BranchedOperator's branches are
        shipped as they are (compress them yourself).

    Returns
    -------
    path : pathlib.Path
        Written atomically (a temporary file, then a rename): on any error no file, or the previous one, is left.

    Raises
    ------
    ValueError
        ``op`` is not a DefOp, ``shape`` not a Shape (or of another dimension or mesh than ``op``), ``title``
        not a string, ``path`` not a path, a picture for a 3D operator, a picture without ``shape`` or
        ``image_frame``, or one whose silhouette is not ``shape``'s outline (the message says what to pass),
        ``compress`` not a bool.
    """
    check_compress(compress)
    if isinstance(op, MovableOp):  # handles that move at rest: the page of defop.editor.movable_page
        if image is not None or image_frame is not None:
            raise ValueError("image and image_frame are not offered on the page of a MovableOp")
        return movable_html(op, path, shape=shape, title=title, compress=compress)
    branched = isinstance(op, BranchedOperator)
    if branched:
        if op.branches[0].op.d != 2:
            raise ValueError(f"op: the page of a multi-valued operator is 2D, got a {op.branches[0].op.d}D one")
        bop, op = op, op.branches[0].op
    elif not isinstance(op, DefOp):
        raise ValueError(f"op must be a trained DefOp or BranchedOperator, got {type(op).__name__}")
    if shape is not None and not isinstance(shape, Shape):
        raise ValueError(f"shape must be a Shape (dop.shapes.load(...)) or None, got {type(shape).__name__}")
    _check_dimensions(op, shape, image, image_frame)
    if title is not None:
        title = opt.text("title", title)
    regions = None
    if shape is not None:
        op.check_mesh(shape.mesh)
        regions = (
            region_polygons(shape.P_moving, shape.regions)
            if op.d == 2
            else region_balls(shape.P_moving, shape.regions, op.train_samples)
        )
    if branched:
        payload = branched_to_payload(bop, regions)
    else:
        payload = defop_to_payload(op, regions, page_factors(op, compress))
    if op.d == 3 and shape is not None and shape.surface is not None:
        payload.update(surface_payload(shape.surface, op.n_vertices))
    if not title:  # the shape's name comes from the operator's file: as untrusted as a title
        title = opt.text(
            "title",
            f"defop: {op.meta.get('shape', 'shape')}, Ψ = {op.handle_basis.kind}"
            + (f", {len(bop)} branches" if branched else ""),
        )
    payload.update(title=title, kinds=[op.handle_basis.kind])
    if image is not None or image_frame is not None:
        payload.update(image_for(op.mesh, image, _frame(image, image_frame, shape)))
    meta, data = encode_payload(compact_payload(payload))
    fields = dict(
        title=html.escape(title),
        meta=script_json(meta),
        data=base64.b64encode(data).decode("ascii"),
        factor=payload["extrapolation_factor"],
    )
    if op.d == 3:
        text = _PAGE_3D.format(
            js=solid_script(), three_version=THREE_VERSION, surface_legend=_surface_legend(payload), **fields
        )
    else:
        page = _PAGE_BRANCHED if branched else _PAGE
        text = page.format(js=_inline_script(JS_PATH.read_text(encoding="utf-8")), **fields)
    return opt.write_atomic(path, text.encode("utf-8"))


def movable_html(op, path, shape=None, title=None, compress=True):
    """Write the page of a MovableOp (:func:`to_html` with a MovableOp; :mod:`.movable_page`): the 2D page, or the
    3D view, with the rest mode, ``defop_movable.js`` after the editor's (and the 3D view's) script. ``shape``'s
    sampling regions are drawn around the nominal rest positions in 2D, and in 3D its surface is the one drawn (its
    mesh must be the operator's). ``compress`` as :func:`to_html`'s: the fixed-P page's factors
    (:func:`.payload.page_factors`: ``op``'s own or :meth:`MovableOp.compress
    <defop.operator.movable.MovableOp.compress>`'s, B on its grid and Rice-coded, :func:`.compact.compact_payload`);
    the handles and the rest pose stay exact (the correction writes them). Returns the path, written atomically."""
    if title is not None:
        title = opt.text("title", title)
    regions = None
    if shape is not None:
        if not isinstance(shape, Shape):
            raise ValueError(f"shape must be a Shape (dop.shapes.load(...)) or None, got {type(shape).__name__}")
        _check_dimensions(op, shape, None, None)
        check_mesh(op, shape.mesh)
        regions = region_polygons(shape.P_moving, shape.regions) if op.d == 2 else None
    payload = movable_to_payload(op, regions, page_factors(op, compress))
    if op.d == 3 and shape is not None and shape.surface is not None:
        payload.update(surface_payload(shape.surface, op.n_vertices))
    if not title:
        title = opt.text(
            "title", f"defop: {op.meta.get('shape', 'shape')}, {op.placement.n_movable} movable rest handle(s)"
        )
    payload.update(title=title, kinds=["tps"])
    meta, data = encode_payload(compact_payload(payload, drawn_payload))  # in 3D the drawn and placement vertices
    fields = dict(
        title=html.escape(title),
        meta=script_json(meta),
        data=base64.b64encode(data).decode("ascii"),
        factor=EXTRAPOLATION_FACTOR,
    )
    if op.d == 2:
        text = movable_page(_PAGE, 2).format(js=_inline_script(movable_script()), **fields)
    else:
        js, drawn = solid_script(MOVABLE_JS_PATH), _surface_legend(payload)
        text = movable_page(_PAGE_3D, 3).format(js=js, three_version=THREE_VERSION, surface_legend=drawn, **fields)
    return opt.write_atomic(path, text.encode("utf-8"))


def _surface_legend(payload):
    """The 3D page's legend words for the surface it draws."""
    if "surface_F" in payload:
        return "the shape's surface, carried by the tetrahedra"
    return "boundary surface of the tetrahedral mesh"


def _vendored(name):
    """A vendored three.js file's text, checked against its pinned sha256 (:data:`THREE_FILES`)."""
    raw = (THREE_DIR / name).read_bytes()
    digest = hashlib.sha256(raw).hexdigest()
    if digest != THREE_FILES[name]:
        raise RuntimeError(
            f"{THREE_DIR / name} has sha256 {digest}, not the pinned {THREE_FILES[name]} "
            f"(see {THREE_DIR / 'README.md'})"
        )
    return raw.decode("utf-8")


def _module_as_function(text, name):
    """An ES module's text as an expression: ``(() => { body; return {exported names}; })()``.

    Only the shape of the vendored bundle is accepted: no ``import`` and exactly one final ``export { a as B, ... };``
    statement.
    """
    found = list(re.finditer(r"export\s*\{([^}]*)\}\s*;?\s*$", text))
    if len(found) != 1 or re.search(r"^\s*import[\s{]", text, flags=re.M) or "export " in text[: found[0].start()]:
        raise RuntimeError(f"{name}: not the module shape the page expects (one final export statement)")
    items = []
    for item in found[0].group(1).split(","):
        parts = item.split(" as ")
        local, exported = parts[0].strip(), parts[-1].strip()
        items.append(f"{exported}: {local}" if exported != local else local)
    body = text[: found[0].start()]
    return f"(() => {{\n{body}\nreturn {{ {', '.join(items)} }};\n}})()"


def solid_script(*after):
    """The 3D page's inline module: the vendored three.js bundle (sha256-checked) as the binding ``THREE`` and its
    ``OrbitControls``, then ``defop_editor.js`` verbatim (the one evaluator) and ``defop_solid.js`` without its
    import line (the names it imports are in the same module scope), then the scripts ``after`` the same way (the
    movable page's ``defop_movable.js``).

    Parameters
    ----------
    *after : pathlib.Path

    Returns
    -------
    str
    """
    solid = script_after_editor(SOLID_JS_PATH)
    name = next(iter(THREE_FILES))
    parts = [
        "const THREE = " + _module_as_function(_vendored(name), name) + ";",
        "const { OrbitControls } = THREE;",
        JS_PATH.read_text(encoding="utf-8"),
        solid,
        *(script_after_editor(path) for path in after),
    ]
    return _inline_script("\n".join(parts))


def script_json(value):
    """``value`` as JSON that is safe inside an inline ``<script>``: ASCII only, with ``<``, ``>`` and ``&`` escaped.

    Inside a script element the HTML parser ends the script at ``</script`` and enters an escaped state at
    ``<!--`` (where a later ``<script`` hides the real end tag), whatever the JavaScript means. Outside JSON
    strings these characters cannot occur, and inside them ``\\u003c`` is the same character to JavaScript.

    Returns
    -------
    str
    """
    text = json.dumps(value, ensure_ascii=True)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _inline_script(js):
    """The editor's own script, checked to hold nothing that ends or escapes an inline ``<script>``."""
    lowered = js.lower()
    for bad in ("</script", "<!--", "<script"):
        if bad in lowered:
            raise RuntimeError(f"{JS_PATH.name} contains {bad!r}, which would break the inline script of the page")
    return js
