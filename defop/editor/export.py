"""The standalone page: one self-contained HTML file that drags a DefOp offline (no Python, no network)."""

from __future__ import annotations

import base64
import html
import json

from .. import options as opt
from ..operator.defop import DefOp
from ..scene.shapes import Shape
from .payload import JS_PATH, defop_to_payload, encode_payload, image_for
from .state import region_polygons

_PAGE = """<!DOCTYPE html>
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
<p class="defop-instruction">Drag a red handle with the mouse: the shape follows, computed in this page.</p>
<div id="defop-app"></div>
<div class="defop-legend" aria-label="legend">
<span><i class="defop-swatch" style="border-radius:50%;background:#d62728;border:1px solid #000"></i>moving handle
(drag it)</span>
<span><i class="defop-swatch" style="border-radius:50%;background:#1f77b4;border:1px solid #000"></i>fixed
handle</span>
<span><i class="defop-swatch" style="background:rgba(255,127,14,0.10);border:1px solid rgba(255,127,14,0.7)"></i>
sampling region of a handle (a disc around it, its Voronoi cell, or both): the positions it was trained on</span>
<span><i class="defop-swatch" style="border-radius:50%;border:2px solid #b00"></i>handle outside its region: the
operator extrapolates</span>
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


def to_html(op, path, shape=None, title=None, image=None, image_frame=None):
    """Write one self-contained page that drags ``op`` offline (inline script, no network access).

    Parameters
    ----------
    op : defop.operator.DefOp
    path : str or pathlib.Path
    shape : defop.scene.shapes.Shape, optional
        Its sampling regions are drawn and used for the extrapolation warning; default: discs through the
        farthest training sample of each handle.
    title : str, optional
        Any string: it is shown as text (HTML-escaped in ``<title>``, JSON-escaped in the inline script, where
        ``<``, ``>`` and ``&`` become ``\\u003c``, ``\\u003e``, ``\\u0026`` so no ``</script>`` or ``<!--`` can end
        or break the script). A lone surrogate becomes U+FFFD.
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path, optional
        A picture drawn on the deformed mesh (see :func:`image_payload`); inlined as a PNG.
    image_frame : callable or (n_vertices,2) numpy array
        Required with ``image``: the mesh → pixel map or the rest vertices in pixels (:func:`pixel_coordinates`).

    Returns
    -------
    path : pathlib.Path
        Written atomically (a temporary file, then a rename): on any error no file, or the previous one, is left.

    Raises
    ------
    ValueError
        ``op`` is not a DefOp, ``shape`` not a Shape, ``title`` not a string, ``path`` not a path.
    """
    if not isinstance(op, DefOp):
        raise ValueError(f"op must be a trained DefOp, got {type(op).__name__}")
    if shape is not None and not isinstance(shape, Shape):
        raise ValueError(f"shape must be a Shape (dop.shapes.load(...)) or None, got {type(shape).__name__}")
    if title is not None:
        title = opt.text("title", title)
    regions = None
    if shape is not None:
        op.check_mesh(shape.mesh)
        regions = region_polygons(shape.P_moving, shape.regions)
    payload = defop_to_payload(op, regions)
    if not title:  # the shape's name comes from the operator's file: as untrusted as a title
        title = opt.text("title", f"defop: {op.meta.get('shape', 'shape')}, Ψ = {op.handle_basis.kind}")
    payload.update(title=title, kinds=[op.handle_basis.kind])
    if image is not None or image_frame is not None:
        payload.update(image_for(op.mesh, image, image_frame))
    meta, data = encode_payload(payload)
    text = _PAGE.format(
        title=html.escape(title),
        js=_inline_script(JS_PATH.read_text(encoding="utf-8")),
        meta=script_json(meta),
        data=base64.b64encode(data).decode("ascii"),
    )
    return opt.write_atomic(path, text.encode("utf-8"))


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
