"""The in-browser editor: D(·, Q) evaluated in the page, not through the kernel (issue #18).

Python sends the trained operator once (:func:`defop_to_payload`: Ψ's kind and centres or monomial
plan, the float32 factors, the mesh and the handles); ``static/defop_editor.js`` evaluates
D(·, Q) = x + δψ(Q) A B (Eq. 3 in the form (★) of :mod:`defop.operator`) on every pointer move with
the formulas of :mod:`defop.handle_bases` and draws the mesh on a canvas. The kernel is used only for
what must run in Python: the ground-truth overlay (a warm-started solve of problem 6), switching basis
or shape, and reading Q back on release.

- :class:`BrowserEditor`: the Jupyter widget (anywidget), a view of an :class:`~defop.editor_state.EditorState`;
- :func:`to_html`: one self-contained offline page dragging the same operator (no Python, no network).

Example
-------
>>> editor = BrowserEditor("bar", m=40)   # doctest: +SKIP
>>> editor                                # drag in the page; editor.Q follows on release   # doctest: +SKIP
>>> to_html(editor.state.operator, "bar.html", shape=editor.state.shape)   # doctest: +SKIP
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import anywidget
import numpy as np
import traitlets

from .editor_state import EditorState, ground_truth_text, reach_polygons, region_polygons

JS_PATH = Path(__file__).with_name("static") / "defop_editor.js"
_DTYPES = {"f8": np.float64, "f4": np.float32, "i4": np.int32, "u1": np.uint8}


def mesh_edges(F):
    """Unique edges of a triangle mesh.

    Parameters
    ----------
    F : (m,3) int numpy array

    Returns
    -------
    E : (e,2) int numpy array
    """
    E = np.sort(np.asarray(F)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(E, axis=0)


def _polynomial_plan(monomials):
    """Each monomial of degree ≥ 1 as (parent monomial index, z coordinate): ψ_j = ψ_parent · z_factor."""
    index = {m: i for i, m in enumerate(monomials)}
    parent = [index[m[:-1]] if len(m) > 1 else 0 for m in monomials[1:]]
    factor = [m[-1] for m in monomials[1:]]
    return np.array(parent, np.int32), np.array(factor, np.int32)


def defop_to_payload(op, regions=None):
    """Everything the page needs to evaluate and draw a DefOp: the one place that reads its internals.

    Parameters
    ----------
    op : defop.operator.DefOp
        Uses the compressed factors ``(A, B)`` of W_F when present, otherwise W_F (W[1:] with the handle
        columns zeroed) as a single factor: the page evaluates (★) of :mod:`defop.operator`.
    regions : list of list of (k,2) numpy array, optional
        Sampling-region polygons per moving handle (:func:`defop.editor_state.region_polygons`); default:
        discs through the farthest training sample.

    Returns
    -------
    payload : dict
        Scalars (``kind``, ``size``, ``n_moving``, ``n_vertices``, ``scale``, ``rank``, ``regions``) and
        numpy arrays (``P``, ``centers`` or ``parent``/``factor``, ``A``, ``B``, ``V``, ``F``, ``E``,
        ``handles``, ``moving``), each flattened row-major by :func:`encode_payload`.
    """
    basis = op.handle_basis
    if regions is None:
        regions = reach_polygons(op.P, op.train_samples)
    p = {
        "kind": basis.kind,
        "size": int(basis.size),
        "n_moving": int(basis.n_handles),
        "n_vertices": int(op.n_vertices),
        "scale": float(basis.scale),
        "regions": [[np.asarray(poly, float).ravel().tolist() for poly in polys] for polys in regions],
        "P": np.asarray(basis.P, np.float64),
        "V": np.asarray(op.mesh.V, np.float64),
        "F": np.asarray(op.mesh.F, np.int32),
        "E": mesh_edges(op.mesh.F).astype(np.int32),
        "handles": np.asarray(op.handles, np.int32),
        "moving": np.asarray(op.moving, np.uint8),
    }
    if basis.kind == "tps":
        p["centers"] = np.asarray(basis.z(basis.centers), np.float64)  # z_k = (Q_k − P)/scale, (m, 2n)
    else:
        p["parent"], p["factor"] = _polynomial_plan(basis.monomials)
    # (★) of defop.operator: D(·, Q) = x + δψ(Q) W_F, the moving handles' columns set to Q − P exactly
    if op.factors is not None:
        p["A"], p["B"] = (np.asarray(f, np.float32) for f in op.factors)
        p["rank"] = int(p["A"].shape[1])
    else:
        p["A"] = np.asarray(op._WF, np.float32)  # W[1:] with the handle columns zeroed
    return p


def encode_payload(payload):
    """Split a payload into JSON metadata and one byte buffer (arrays at 8-byte-aligned offsets).

    Returns
    -------
    meta : dict
        ``{"scalars": {...}, "arrays": {name: {"dtype", "shape", "offset", "length"}}}``
    data : bytes
    """
    codes = {np.dtype(v): k for k, v in _DTYPES.items()}
    scalars, arrays, chunks, offset = {}, {}, [], 0
    for name, value in payload.items():
        if not isinstance(value, np.ndarray):
            scalars[name] = value
            continue
        a = np.ascontiguousarray(value)
        raw = a.tobytes()
        arrays[name] = {"dtype": codes[a.dtype], "shape": list(a.shape), "offset": offset, "length": int(a.size)}
        pad = -len(raw) % 8
        chunks.append(raw + b"\0" * pad)
        offset += len(raw) + pad
    return {"scalars": scalars, "arrays": arrays}, b"".join(chunks)


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<meta http-equiv="Content-Security-Policy"
 content="default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'">
</head><body style="margin:12px">
<div id="defop-app"></div>
<p style="font:12px system-ui;color:#555">Drag a red handle. D(x, Q) = &Sigma;<sub>ij</sub> C<sub>ij</sub>
&phi;<sub>i</sub>(x) &psi;<sub>j</sub>(Q) (Eq. 3 of Poranne &amp; Lipman) is evaluated in this page;
written by defop.</p>
<script type="module">
{js}
window.defopEditor = mountStandalone(document.getElementById("defop-app"), {meta}, "{data}");
</script>
</body></html>
"""


def to_html(op, path, shape=None, title=None):
    """Write one self-contained page that drags ``op`` offline (inline script, no network access).

    Parameters
    ----------
    op : defop.operator.DefOp
    path : str or pathlib.Path
    shape : defop.shapes.Shape, optional
        Its sampling regions are drawn and used for the extrapolation warning; default: discs through the
        farthest training sample of each handle.
    title : str, optional

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


class BrowserEditor(anywidget.AnyWidget):
    """Drag the handles of a shape in the page; D(·, Q) is evaluated in JavaScript.

    Parameters
    ----------
    shape : defop.shapes.Shape or str
    operators : dict, optional
        Trained DefOps by basis kind.
    shapes : sequence of str, optional
        Shape names offered in the page (switching trains in the kernel).
    **state_kw
        Passed to :class:`~defop.editor_state.EditorState` (``basis``, ``energy``, ``m``, ``kinds``,
        ``trainer``, ``solver``, ``pick_radius``).

    Attributes
    ----------
    state : defop.editor_state.EditorState
    """

    _esm = JS_PATH.read_text()
    payload_meta = traitlets.Dict().tag(sync=True)
    payload_data = traitlets.Bytes().tag(sync=True)
    q = traitlets.List().tag(sync=True)
    basis = traitlets.Unicode().tag(sync=True)
    shape_name = traitlets.Unicode().tag(sync=True)
    ground_truth = traitlets.Bool(False).tag(sync=True)
    gt_meta = traitlets.Dict().tag(sync=True)
    gt_data = traitlets.Bytes().tag(sync=True)

    def __init__(self, shape, operators=None, *, shapes=None, **state_kw):
        super().__init__()
        self._state_kw = state_kw
        self._shapes = list(shapes or [])
        self._syncing = False
        self.state = EditorState(shape, operators, **state_kw)
        self._send_operator()
        self.observe(self._on_q, names="q")
        self.observe(self._on_basis, names="basis")
        self.observe(self._on_shape, names="shape_name")
        self.observe(self._on_ground_truth, names="ground_truth")

    @property
    def Q(self):
        """(n,2) numpy array: the moving handles, as last released in the page (or set from Python)."""
        return self.state.Q.copy()

    def set_Q(self, Q):
        """Move the handles from Python; the page follows."""
        self.state.set_Q(Q)
        self._sync(q=self.state.Q.ravel().tolist())
        self._send_ground_truth()

    def _repr_mimebundle_(self, **kwargs):
        """The live widget plus a static fallback (:func:`defop.widgets.static_bundle`): a picture of the
        editor and one line of text, which a stored notebook shows without a kernel."""
        from .widgets import static_bundle  # matplotlib only when displayed

        bundle = super()._repr_mimebundle_(**kwargs) or {}
        if isinstance(bundle, tuple):  # (data, metadata)
            bundle = bundle[0]
        return {**bundle, **static_bundle(self.state)}

    def _sync(self, **traits):
        self._syncing = True
        try:
            with self.hold_sync():
                for name, value in traits.items():
                    setattr(self, name, value)
        finally:
            self._syncing = False

    def _send_operator(self):
        s = self.state
        payload = defop_to_payload(s.operator, s.regions)
        payload.update(
            title=f"{s.shape.name}: {s.energy} DefOp, Ψ = {s.kind}", kinds=list(s.kinds), shape=s.shape.name,
            shapes=self._shapes, pick_radius=s.pick_radius,
        )
        meta, data = encode_payload(payload)
        self._sync(payload_meta=meta, payload_data=data, q=s.Q.ravel().tolist(), basis=s.kind,
                   shape_name=s.shape.name)
        self._send_ground_truth()

    def _send_ground_truth(self):
        s = self.state
        if s.gt_enabled and s.X_gt is not None:
            self._sync(gt_meta={"text": ground_truth_text(s)}, gt_data=s.X_gt.astype(np.float32).tobytes())
        else:
            self._sync(gt_meta={"text": ""}, gt_data=b"")

    def _on_q(self, change):
        if self._syncing:
            return
        self.state.set_Q(np.reshape(change["new"], (-1, 2)))
        self._send_ground_truth()

    def _on_basis(self, change):
        if not self._syncing:
            self.state.set_basis(change["new"])
            self._send_operator()

    def _on_shape(self, change):
        if not self._syncing:
            self.state = EditorState(change["new"], **self._state_kw)
            self._send_operator()

    def _on_ground_truth(self, change):
        if not self._syncing:
            self.state.set_ground_truth(change["new"])
            self._send_ground_truth()
