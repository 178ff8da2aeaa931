"""The standalone page: one self-contained HTML file that drags a DefOp offline (no Python, no network)."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

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
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path, optional
        A picture drawn on the deformed mesh (see :func:`image_payload`); inlined as a PNG.
    image_frame : callable or (n_vertices,2) numpy array
        Required with ``image``: the mesh → pixel map or the rest vertices in pixels (:func:`pixel_coordinates`).

    Returns
    -------
    path : pathlib.Path
    """
    regions = None
    if shape is not None:
        op.check_mesh(shape.mesh)
        regions = region_polygons(shape.P_moving, shape.regions)
    payload = defop_to_payload(op, regions)
    title = title or f"defop: {op.meta.get('shape', 'shape')}, Ψ = {op.handle_basis.kind}"
    payload.update(title=title, kinds=[op.handle_basis.kind])
    if image is not None or image_frame is not None:
        payload.update(image_for(op.mesh, image, image_frame))
    meta, data = encode_payload(payload)
    text = _PAGE.format(
        title=html.escape(title),
        js=JS_PATH.read_text(),
        meta=json.dumps(meta).replace("</", "<\\/"),
        data=base64.b64encode(data).decode("ascii"),
    )
    path = Path(path)
    path.write_text(text, encoding="utf-8")
    return path
