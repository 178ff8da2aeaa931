"""Views of the handle editor's state in matplotlib and ipywidgets (the browser view is :mod:`defop.editor.browser`).

The editor is split three ways:

- :class:`defop.editor.state.EditorState`: Q, X = D(·, Q), the operators and the ground truth (pure numpy);
- :class:`CanvasView`: the state drawn on a matplotlib figure. It is the static picture a stored notebook
  keeps (:func:`static_bundle`, used by :class:`defop.editor.browser.BrowserEditor`) and, with ipympl
  (``%matplotlib widget``), a kernel-side editor whose mouse events call :meth:`EditorState.press`,
  :meth:`~EditorState.drag` and :meth:`~EditorState.release`: the comparison of
  ``benchmarks/bench_browser_ipympl.py``;
- :class:`Controls`: the ipywidgets controls (basis, ground truth, reset, sliders, readouts) of a state.

:class:`HandleEditor` puts a canvas and the controls on one state. The playground (notebook 11) uses the
in-page editor :class:`defop.editor.browser.BrowserEditor` instead: its frame loop runs in the browser.
"""

from __future__ import annotations

import base64
import html
import io
import json

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from .state import EditorState, readout_text

__all__ = ["CanvasView", "Controls", "HandleEditor", "static_bundle", "static_png"]

_FACE = np.array([0.80, 0.88, 0.97, 1.0])  # light blue
_FACE_FLIPPED = np.array([0.97, 0.55, 0.50, 1.0])  # salmon: det J <= 0
_EDGE = (0.29, 0.43, 0.65, 1.0)
_REGION = (0.95, 0.55, 0.10, 0.9)


class CanvasView:
    """A matplotlib picture of an :class:`~defop.editor.state.EditorState`, redrawn by :meth:`refresh`.

    Parameters
    ----------
    state : defop.editor.state.EditorState
    interactive : bool
        Create the figure with pyplot (an ipympl canvas under ``%matplotlib widget``) and connect the mouse
        to the state's drag methods; False draws on a plain Agg :class:`~matplotlib.figure.Figure`, with the
        sampling regions (dashed; left out of the interactive canvas, which redraws every artist per frame).
    figsize : (2,) tuple, optional
        Inches; default from the shape's aspect ratio.
    on_change : callable, optional
        Called with no argument after a mouse event changed the state (the controls refresh their readouts).
    """

    def __init__(self, state, *, interactive=True, figsize=None, on_change=None):
        self.state, self.on_change = state, on_change
        V = state.mesh.V
        lo, hi = V.min(axis=0), V.max(axis=0)
        margin = 0.3 * state.diag
        self.xlim = (float(lo[0] - margin), float(hi[0] + margin))
        self.ylim = (float(lo[1] - margin), float(hi[1] + margin))
        if figsize is None:
            aspect = (self.ylim[1] - self.ylim[0]) / (self.xlim[1] - self.xlim[0])
            figsize = (6.0, float(np.clip(6.0 * aspect + 0.4, 2.5, 5.0)))
        if interactive:
            with plt.ioff():
                self.fig = plt.figure(figsize=figsize)
            for name in ("header_visible", "footer_visible", "resizable"):
                if hasattr(self.fig.canvas, name):  # ipympl Canvas widget
                    setattr(self.fig.canvas, name, False)
        else:
            self.fig = Figure(figsize=figsize)
        self.ax = self.fig.add_subplot()
        self._build_artists(regions=not interactive)
        self.fig.tight_layout()
        self._cids = []
        if interactive:
            self._cids = [
                self.fig.canvas.mpl_connect(name, handler)
                for name, handler in (
                    ("button_press_event", self._press),
                    ("motion_notify_event", self._motion),
                    ("button_release_event", self._release),
                )
            ]
        self.refresh()

    def _build_artists(self, regions):
        s, ax = self.state, self.ax
        ax.set_xlim(*self.xlim)
        ax.set_ylim(*self.ylim)
        ax.set_aspect("equal", adjustable="box")
        ax.set_autoscale_on(False)
        ax.set_xticks([])
        ax.set_yticks([])
        for polys in s.regions if regions else []:  # the static picture only: ipympl redraws every artist
            for poly in polys:
                ax.plot(*np.vstack([poly, poly[:1]]).T, color=_REGION, lw=0.8, ls="--", zorder=1)
        F = s.mesh.F
        self._mesh = PolyCollection(s.X[F], facecolors=_FACE, edgecolors=_EDGE, linewidths=0.3, zorder=2)
        ax.add_collection(self._mesh, autolim=False)
        self._gt = PolyCollection(
            s.X[F], facecolors="none", edgecolors=(0.8, 0.1, 0.1, 0.7), linewidths=0.5, visible=False, zorder=3
        )
        ax.add_collection(self._gt, autolim=False)
        fixed = s.mesh.V[s.shape.fixed_handles] if len(s.shape.fixed_handles) else np.zeros((0, 2))
        ax.plot(*s.P.T, "o", ms=9, mfc="none", mec="0.55", mew=1.0, zorder=4)
        ax.plot(*fixed.T, "s", ms=7, color="0.15", zorder=4)
        (self._handles,) = ax.plot(*s.Q.T, "o", ms=9, color="C3", mec="k", mew=0.8, zorder=5)
        (self._active,) = ax.plot([], [], "o", ms=15, mfc="none", mec="C3", mew=2.0, zorder=6)

    def refresh(self):
        """Redraw the state: mesh (flipped triangles salmon), handles, the dragged handle, the ground truth."""
        s = self.state
        F = s.mesh.F
        self._mesh.set_verts(s.X[F])
        colors = np.tile(_FACE, (len(F), 1))
        colors[s.flipped] = _FACE_FLIPPED
        self._mesh.set_facecolors(colors)
        self._handles.set_data(*s.Q.T)
        self._active.set_data(*(s.Q[[s.active]].T if s.active is not None else ([], [])))
        show = s.gt_enabled and s.X_gt is not None
        self._gt.set_visible(show)
        if show:
            self._gt.set_verts(s.X_gt[F])
        size = s.operator.handle_basis.size
        self.ax.set_title(f"{s.shape.name}: {s.kind} DefOp, |Ψ| = {size} ({s.energy})", fontsize=10)
        self.fig.canvas.draw_idle()

    def handle_fractions(self):
        """Moving handles on the canvas as fractions ``(u, v)`` of its width and height from the top left.

        Returns
        -------
        (n,2) numpy array
        """
        self.ax.apply_aspect()
        disp = self.ax.transData.transform(self.state.Q)
        return np.column_stack([disp[:, 0] / self.fig.bbox.width, 1.0 - disp[:, 1] / self.fig.bbox.height])

    def png(self, dpi=72):
        """The canvas as PNG bytes."""
        buf = io.BytesIO()
        self.fig.savefig(buf, format="png", dpi=dpi)
        return buf.getvalue()

    # mouse events -> the state's drag methods
    def _data(self, event):
        if event.x is None or event.y is None:
            return None
        return tuple(float(v) for v in self.ax.transData.inverted().transform((event.x, event.y)))

    def _changed(self):
        self.refresh()
        if self.on_change is not None:
            self.on_change()

    def _press(self, event):
        toolbar = getattr(self.fig.canvas, "toolbar", None)
        if event.inaxes is self.ax and event.button == 1 and not getattr(toolbar, "mode", ""):
            if self.state.press(event.xdata, event.ydata) is not None:
                self._changed()

    def _motion(self, event):
        xy = self._data(event)  # also valid outside the axes
        if xy is not None and self.state.drag(*xy):
            self._changed()

    def _release(self, event):
        if self.state.release(*(self._data(event) or (None, None))):
            self._changed()

    def close(self):
        """Disconnect the mouse and close the figure."""
        for cid in self._cids:
            self.fig.canvas.mpl_disconnect(cid)
        self._cids = []
        plt.close(self.fig)


class Controls:
    """ipywidgets controls of an :class:`~defop.editor.state.EditorState`: basis, ground truth, reset, sliders.

    Parameters
    ----------
    state : defop.editor.state.EditorState
    on_change : callable, optional
        Called with no argument after a control changed the state (a view redraws).
    """

    def __init__(self, state, on_change=None):
        self.state, self.on_change = state, on_change
        self._syncing = False
        self.basis = widgets.Dropdown(
            options=list(state.kinds), value=state.kind, description="Ψ basis", layout=widgets.Layout(width="200px")
        )
        self.basis.observe(self._act(state.set_basis), names="value")
        self.ground_truth = widgets.ToggleButton(value=False, description="Ground truth", icon="check")
        self.ground_truth.observe(self._act(state.set_ground_truth), names="value")
        self.reset = widgets.Button(description="Reset", icon="undo", tooltip="back to the rest pose")
        self.reset.on_click(lambda _button: self._act(lambda _v: state.reset())({"new": None}))
        self.readout = widgets.HTML()
        self.readout.add_class("defop-readout")
        self.handle_readout = widgets.HTML()
        self.handle_readout.add_class("defop-handles")
        d, (x0, y0) = state.diag, state.mesh.V.min(axis=0) - 0.3 * state.diag
        x1, y1 = state.mesh.V.max(axis=0) + 0.3 * state.diag
        self.sliders = [
            tuple(
                widgets.FloatSlider(
                    value=float(p[c]),
                    min=float(lo),
                    max=float(hi),
                    step=d / 1000.0,
                    description=f"q{i} {'xy'[c]}",
                    readout_format=".3f",
                    layout=widgets.Layout(width="320px"),
                )
                for c, (lo, hi) in enumerate(((x0, x1), (y0, y1)))
            )
            for i, p in enumerate(state.P)
        ]
        for i, pair in enumerate(self.sliders):
            for c, slider in enumerate(pair):
                slider.observe(self._slide(i, c), names="value")
        self.box = widgets.HBox([self.basis, self.ground_truth, self.reset])
        self.slider_box = widgets.Accordion(
            children=[widgets.VBox([widgets.HBox(list(p)) for p in self.sliders])], titles=("Handle sliders",)
        )
        self.slider_box.selected_index = None
        self.refresh()

    def _act(self, method):
        def callback(change):
            if not self._syncing:
                try:
                    method(change["new"])
                except Exception:
                    self.refresh()  # the control shows the state again: a rejected value changes nothing
                    raise
                self.refresh()
                if self.on_change is not None:
                    self.on_change()

        return callback

    def _slide(self, i, c):
        def move(value):
            q = self.state.Q[i].copy()
            q[c] = value
            self.state.set_handle(i, q)

        return self._act(move)

    def refresh(self, positions=None):
        """Controls and readouts follow the state (without calling back into it).

        Parameters
        ----------
        positions : (n,2) numpy array, optional
            Handle positions on the canvas as fractions (:meth:`CanvasView.handle_fractions`), written into
            the handle readout's ``data-uv`` for the benchmark's pointer (the last ones given are kept).
        """
        s = self.state
        if positions is not None:
            self._positions = np.round(positions, 6).tolist()
        self._syncing = True
        try:
            self.basis.value, self.ground_truth.value = s.kind, s.gt_enabled
            for (sx, sy), q in zip(self.sliders, s.Q, strict=True):
                sx.value, sy.value = float(np.clip(q[0], sx.min, sx.max)), float(np.clip(q[1], sy.min, sy.max))
        finally:
            self._syncing = False
        self.readout.value = f"<span>{html.escape(readout_text(s))}</span>"
        Q = np.round(s.Q, 6).tolist()
        uv = json.dumps(getattr(self, "_positions", []))
        text = ", ".join(f"q{i} = ({q[0]:.3f}, {q[1]:.3f})" for i, q in enumerate(Q))
        self.handle_readout.value = (
            f"<span class='defop-handle-data' data-q='{json.dumps(Q)}' data-uv='{uv}'>{html.escape(text)}</span>"
        )


class HandleEditor:
    """The kernel-side editor: a matplotlib (ipympl) canvas and ipywidgets controls on one state.

    Every pointer move goes through the kernel, so this is the comparison for the in-page editor
    (:class:`defop.editor.browser.BrowserEditor`) in ``benchmarks/bench_browser_ipympl.py``.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape or str
    operators : dict, optional
    figsize : (2,) tuple, optional
    **state_kw
        Passed to :class:`~defop.editor.state.EditorState`.

    Attributes
    ----------
    state : defop.editor.state.EditorState
    canvas : CanvasView
    controls : Controls
    """

    def __init__(self, shape, operators=None, *, figsize=None, **state_kw):
        self.state = shape if isinstance(shape, EditorState) else EditorState(shape, operators, **state_kw)
        self.canvas = CanvasView(self.state, figsize=figsize, on_change=self._canvas_changed)
        self.controls = Controls(self.state, on_change=self._controls_changed)
        self._canvas_changed()

    def _canvas_changed(self):
        if hasattr(self, "controls"):
            self.controls.refresh(self.canvas.handle_fractions())

    def _controls_changed(self):
        self.canvas.refresh()
        self._canvas_changed()

    @property
    def widget(self):
        """The editor as one ipywidget: controls, canvas (a picture without ipympl), readouts, sliders."""
        view = self.canvas.fig.canvas
        if not isinstance(view, widgets.DOMWidget):  # not ipympl: a static picture
            view = widgets.Image(value=self.canvas.png(), format="png")
        c = self.controls
        return widgets.VBox([c.box, view, c.readout, c.handle_readout, c.slider_box])

    def _ipython_display_(self):
        from IPython.display import display

        display(self.widget)

    def close(self):
        """Close the figure."""
        self.canvas.close()


def static_png(state, dpi=72):
    """A PNG picture of the state (drawn off-screen by :class:`CanvasView`).

    Returns
    -------
    bytes
    """
    view = CanvasView(state, interactive=False)
    return view.png(dpi)


def static_bundle(state, dpi=72):
    """A picture of the editor and one line of text: what a stored notebook shows without a kernel.

    Parameters
    ----------
    state : defop.editor.state.EditorState
    dpi : int

    Returns
    -------
    bundle : dict
        ``{"image/png": base64 str, "text/plain": str}``.
    """
    shape = state.shape
    text = (
        f"Handle editor: {shape.name}, {shape.mesh.n_vertices} vertices, {len(state.P)} moving handle(s), "
        f"the {state.kind} DefOp (run the notebook to drag the handles)"
    )
    return {"image/png": base64.b64encode(static_png(state, dpi)).decode("ascii"), "text/plain": text}
