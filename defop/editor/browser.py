"""The in-browser editor: D(·, Q) evaluated in the page, not through the kernel.

Python sends the trained operator once (:func:`defop_to_payload`: Ψ's kind and centres or monomial
plan, the float32 factors, the mesh and the handles); ``static/defop_editor.js`` evaluates
D(·, Q) = x + δψ(Q) A B (Eq. 3 in the form (★) of :mod:`defop.operator.defop`) on every pointer move with
the formulas of :mod:`defop.operator.handle_bases` and draws the mesh on a canvas. The kernel is used only for
what must run in Python: the ground-truth overlay (a warm-started solve of problem 6), switching basis
or shape, and reading Q back on release.

- :class:`BrowserEditor`: the Jupyter widget (anywidget), a view of an :class:`~defop.editor.state.EditorState`;
- :func:`defop.editor.export.to_html`: one self-contained offline page dragging the same operator (no Python,
  no network).

Both can show a picture on the mesh (notebook 13): :func:`image_payload` sends it once as a PNG with one
texture coordinate per vertex (the rest vertex in the picture's pixels, as in :mod:`defop.view.warp`), and the page
draws the deformed mesh textured in WebGL, so the picture warps piecewise affinely at every pointer move.

Example
-------
>>> editor = BrowserEditor("bar", m=40)   # doctest: +SKIP
>>> editor                                # drag in the page; editor.Q follows on release   # doctest: +SKIP
>>> export.to_html(editor.state.operator, "bar.html", shape=editor.state.shape)   # doctest: +SKIP
>>> _, to_pixels = defop.view.warp.image_to_mesh_frame(mask, shape.mesh)          # doctest: +SKIP
>>> BrowserEditor(shape, {"tps": op}, image=picture, image_frame=to_pixels)  # doctest: +SKIP
"""

from __future__ import annotations

import anywidget
import numpy as np
import traitlets

from .. import options as opt
from ..scene.shapes import names as shape_names
from .logic import STATE, restoring
from .movable_page import movable_script, movable_to_payload
from .payload import defop_to_payload, encode_payload, image_for
from .state import EditorState, ground_truth_text, region_polygons


class BrowserEditor(anywidget.AnyWidget):
    """Drag the handles of a shape in the page; D(·, Q) is evaluated in JavaScript.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape or str
    operators : dict, optional
        Trained DefOps by basis kind.
    shapes : sequence of str, optional
        Shape names offered in the page (switching trains in the kernel); not with ``image``.
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path, optional
        A picture drawn on the deformed mesh as a WebGL texture, so dragging a handle warps it (notebook 13).
        Grey, RGB or RGBA; bool, integer or float in [0,1]. Sent to the page once, as a PNG
        (:func:`image_payload`; at most :data:`MAX_IMAGE_SIDE` pixels per side).
    image_frame : callable or (n_vertices,2) numpy array
        Required with ``image``: where the rest mesh lies in the picture, as a mesh → pixel map such as the
        second result of :func:`defop.view.warp.image_to_mesh_frame` ``(mask, shape.mesh)``, or as the rest vertices
        in pixels (x = column, y = row down).
    **state_kw
        Passed to :class:`~defop.editor.state.EditorState` (``basis``, ``energy``, ``m``, ``kinds``,
        ``trainer``, ``solver``, ``pick_radius``).

    Attributes
    ----------
    state : defop.editor.state.EditorState
    """

    _esm = movable_script()  # defop_editor.js, then defop_movable.js (a MovableOp's rest mode)
    payload_meta = traitlets.Dict().tag(sync=True)
    payload_data = traitlets.Bytes().tag(sync=True)
    q = traitlets.List().tag(sync=True)
    rest = traitlets.List().tag(sync=True)  # a MovableOp: its movable handles' rest vertices (the page's rest mode)
    basis = traitlets.Unicode().tag(sync=True)
    shape_name = traitlets.Unicode().tag(sync=True)
    ground_truth = traitlets.Bool(False).tag(sync=True)
    gt_meta = traitlets.Dict().tag(sync=True)
    gt_data = traitlets.Bytes().tag(sync=True)
    image_meta = traitlets.Dict().tag(sync=True)  # the picture: set once, kept across basis switches
    image_data = traitlets.Bytes().tag(sync=True)

    def __init__(self, shape, operators=None, *, shapes=None, image=None, image_frame=None, **state_kw):
        super().__init__()
        if (image is not None or image_frame is not None) and shapes:
            raise ValueError("a picture belongs to one shape's mesh: pass either image or shapes, not both")
        self._state_kw = state_kw
        self._shapes = list(shapes or [])
        unknown = [name for name in self._shapes if not isinstance(name, str) or name not in shape_names()]
        if unknown:  # the page would offer them, and fail only when one is picked
            known = ", ".join(shape_names())
            raise ValueError(f"shapes must be names of built-in shapes ({known}), got {unknown[0]!r}")
        self._syncing = False
        self.state = EditorState(shape, operators, **state_kw)
        if image is not None or image_frame is not None:
            meta, data = encode_payload(image_for(self.state.mesh, image, image_frame))
            self._sync(image_meta=meta, image_data=data)
        self._send_operator()
        self.observe(self._on_q, names="q")
        self.observe(self._on_rest, names="rest")
        self.observe(self._on_basis, names="basis")
        self.observe(self._on_shape, names="shape_name")
        self.observe(self._on_ground_truth, names="ground_truth")

    @property
    def Q(self):
        """(n,2) numpy array: the moving handles, as last released in the page (or set from Python)."""
        return self.state.Q.copy()

    def set_Q(self, Q):
        """Move the handles from Python; the page follows (a rejected Q changes neither)."""
        self.state.set_Q(Q)
        self._sync(q=self.state.Q.ravel().tolist())
        self._send_ground_truth()

    def _repr_mimebundle_(self, **kwargs):
        """The live widget plus a static fallback (:func:`defop.editor.widgets.static_bundle`): a picture of the
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
        if s.rest is None:
            payload = defop_to_payload(s.operator, s.regions)
        else:  # the nominal placement's regions: the page moves them with the rest (the trait rest)
            payload = movable_to_payload(s.operator, region_polygons(s.base_shape.P_moving, s.base_shape.regions))
        payload.update(
            title=f"{s.shape.name}: {s.energy} DefOp, Ψ = {s.kind}",
            kinds=list(s.kinds),
            shape=s.shape.name,
            shapes=self._shapes,
            pick_radius=s.pick_radius,
        )
        meta, data = encode_payload(payload)
        self._sync(payload_meta=meta, payload_data=data, basis=s.kind, shape_name=s.shape.name)
        self._resync()
        self._send_ground_truth()

    def _send_ground_truth(self):
        s = self.state
        if s.gt_enabled and s.X_gt is not None:
            self._sync(gt_meta={"text": ground_truth_text(s)}, gt_data=s.X_gt.astype(np.float32).tobytes())
        else:
            self._sync(gt_meta={"text": ""}, gt_data=b"")

    def _resync(self):
        """The synced traits back to what the state holds (after a value the state rejected)."""
        s = self.state
        rest = [] if s.rest is None else s.rest.tolist()
        name = s.shape.name if s.rest is None else s.base_shape.name
        self._sync(q=s.Q.ravel().tolist(), rest=rest, basis=s.kind, shape_name=name, ground_truth=bool(s.gt_enabled))

    def _apply(self, change, action):
        """Run ``action(new value)`` for a trait the page (or the user) set; a rejected value is undone in the
        traits too, so the page and the state never disagree, and the error is raised."""
        if self._syncing:
            return
        try:
            action(change["new"])
        except Exception:
            self._resync()
            raise

    def _set_q(self, q):
        q = opt.real_array("q", q)
        n = 2 * len(self.state.P)
        if q.shape != (n,):
            raise ValueError(f"q must be a flat list of {n} coordinates (x0, y0, x1, ...), got shape {q.shape}")
        self.state.set_Q(q.reshape(-1, 2))
        self._send_ground_truth()

    def _set_rest(self, rest):
        s = self.state
        if s.rest is None or not isinstance(rest, list) or len(rest) != len(s.rest):
            raise ValueError(
                f"rest must be a list of {0 if s.rest is None else len(s.rest)} vertex indices, got {rest!r}"
            )
        with restoring(s, STATE):  # each movable handle in turn; a refused one undoes the ones before
            for ell, v in enumerate(rest):
                if v != s.rest[ell]:
                    s.set_rest(ell, opt.integer("rest vertex", v))
        self._sync(q=s.Q.ravel().tolist())
        self._send_ground_truth()

    def _set_basis(self, kind):
        self.state.set_basis(kind)
        self._send_operator()

    def _set_shape(self, name):
        self.state = EditorState(name, **self._state_kw)
        self._send_operator()

    def _set_ground_truth(self, enabled):
        self.state.set_ground_truth(enabled)
        self._send_ground_truth()

    def _on_q(self, change):
        self._apply(change, self._set_q)

    def _on_rest(self, change):
        self._apply(change, self._set_rest)

    def _on_basis(self, change):
        self._apply(change, self._set_basis)

    def _on_shape(self, change):
        self._apply(change, self._set_shape)

    def _on_ground_truth(self, change):
        self._apply(change, self._set_ground_truth)
