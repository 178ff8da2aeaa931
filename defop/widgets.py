"""Interactive handle editor: drag the handles of a shape and watch a trained DefOp follow.

This is the playground of the paper's claim that a (Φ, Ψ)-DefOp (Eq. 3) is a closed-form
expression cheap enough for real-time interaction, while the variational DefOp D^E_Φ
(problem 6) has to be solved again for every new handle position Q.

:class:`HandleEditor` holds the state (shape, one trained :class:`~defop.operator.DefOp` per
handle basis Ψ, the current moving-handle positions ``Q (n_moving,2)``) and exposes plain
Python callbacks (:meth:`~HandleEditor.on_press`, :meth:`~HandleEditor.on_motion`,
:meth:`~HandleEditor.on_release`, :meth:`~HandleEditor.set_basis`, :meth:`~HandleEditor.reset`,
:meth:`~HandleEditor.set_ground_truth`, ...). The matplotlib events of the figure are wired to
these callbacks, so the same code runs

- live in JupyterLab or VS Code with ipympl (``%matplotlib widget``), where the figure canvas is
  an ipywidget, and
- headless with the Agg backend in the tests, which call the callbacks directly or fire
  matplotlib ``MouseEvent``s through ``fig.canvas.callbacks.process``.

Artists are updated in place (``set_verts``, ``set_data``) followed by
``fig.canvas.draw_idle()``, so a frame costs one operator evaluation plus one redraw.

Typical use in a notebook::

    %matplotlib widget
    import defop as dop
    editor = dop.widgets.HandleEditor("bar")      # trains the TPS operator (cached on disk)
    editor                                        # canvas + controls; drag the red handles
"""

from __future__ import annotations

import html
import io
import json
import time
import warnings
from importlib.util import find_spec

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

import defop as dop

__all__ = ["BASES", "BASIS_LABELS", "HandleEditor", "min_samples", "shape_picker", "static_bundle"]

#: Handle bases Ψ the editor can switch between (names of :func:`defop.handle_bases.make_basis`).
BASES = ("linear", "quadratic", "cubic", "tps")
BASIS_LABELS = {
    "linear": "Linear",
    "quadratic": "Quadratic",
    "cubic": "Cubic",
    "tps": "TPS",
}

_FACE = np.array([0.80, 0.88, 0.97, 1.0])  # light blue
_FACE_FLIPPED = np.array([0.97, 0.55, 0.50, 1.0])  # salmon: det J <= 0
_EDGE = (0.29, 0.43, 0.65, 1.0)


def _ema(old, new, keep=0.8):
    return new if old is None else keep * old + (1.0 - keep) * new


class HandleEditor:
    """Drag handles of a shape and evaluate a trained (Φ, Ψ)-DefOp D(·, Q) live.

    Parameters
    ----------
    shape : defop.shapes.Shape or str
        The shape (a name is loaded with :func:`defop.shapes.load`).
    operators : dict[str, DefOp], optional
        Already trained operators keyed by handle basis (``"linear"``, ``"quadratic"``, ``"cubic"``,
        ``"tps"``). Missing ones are trained on first use by ``trainer``.
    basis : str
        The handle basis Ψ shown first.
    energy : str
        Energy of the variational DefOp being approximated and of the ground-truth solver
        (``"sarap"``: S-ARAP, Eq. 11; ``"arap"``: Eq. 10).
    m : int, optional
        Number of training samples Q_k passed to :func:`defop.train.train`; None keeps its
        default (which is small in fast mode, ``DEFOP_FAST=1``).
    spatial : str
        Spatial basis Φ, ``"hat"`` or ``"reduced"``.
    seed : int
        Seed of the training samples.
    trainer : callable, optional
        ``trainer(kind) -> DefOp``. Default: :func:`defop.train.train` on ``shape`` with the
        arguments above, ``progress=False`` and the on-disk cache.
    solver : object, optional
        Ground-truth solver with ``solve(targets (h,2), X0=None) -> result`` (``result.X``,
        ``result.converged``). Default: :class:`defop.solve.Solver` built on first use.
    pick_radius : float
        A press picks the nearest moving handle within this distance, as a fraction of the
        bounding-box diagonal of the rest shape.
    gt_layout : {"overlay", "beside"}
        Ground truth drawn as red edges over the approximation, or in a second panel.
    gt_live : {"auto", True, False}
        When the ground truth is on: re-solve on every frame (True), only when the mouse is
        released / the "Solve" button is pressed (False), or on every frame while the last solve
        took less than ``gt_budget`` seconds ("auto").
    gt_budget : float
        Seconds; see ``gt_live``.
    figsize : (2,) tuple, optional
        Figure size in inches.
    train_kw : dict, optional
        Extra keyword arguments for :func:`defop.train.train`.

    Attributes
    ----------
    Q : (n_moving,2) numpy array
        Current positions of the moving handles (row l is handle ``shape.moving_handles[l]``).
    X : (n_vertices,2) numpy array
        Current approximate deformation D_{Φ,Ψ}(·, Q).
    X_gt : (n_vertices,2) numpy array or None
        Last ground truth D^E_Φ(·, Q_gt) (None when off or not computed yet).
    active : int or None
        Index (into the moving handles) of the handle being dragged.
    eval_time : float
        Seconds of the last operator evaluation.
    fps : float or None
        Smoothed rate of interactive frames (drag / slider updates) per second.
    """

    def __init__(
        self,
        shape,
        operators=None,
        *,
        basis="tps",
        energy="sarap",
        m=None,
        spatial="hat",
        seed=0,
        trainer=None,
        solver=None,
        pick_radius=0.05,
        gt_layout="overlay",
        gt_live="auto",
        gt_budget=0.1,
        figsize=None,
        train_kw=None,
    ):
        if isinstance(shape, str):
            shape = dop.shapes.load(shape)
        if basis not in BASES:
            raise ValueError(f"basis {basis!r} is unknown; choose one of {BASES}")
        if gt_layout not in ("overlay", "beside"):
            raise ValueError(f"gt_layout must be 'overlay' or 'beside', got {gt_layout!r}")
        if gt_live not in ("auto", True, False):
            raise ValueError(f"gt_live must be 'auto', True or False, got {gt_live!r}")
        if not pick_radius > 0:
            raise ValueError(f"pick_radius must be positive, got {pick_radius}")
        self.shape = shape
        self.mesh = shape.mesh
        self.energy = energy
        self.m = m
        self.spatial = spatial
        self.seed = seed
        self.train_kw = dict(train_kw or {})
        self.trainer = trainer if trainer is not None else self._train
        self.operators = dict(operators or {})
        for kind in self.operators:
            if kind not in BASES:
                raise ValueError(f"operators has unknown basis {kind!r}; known: {BASES}")
        self._solver = solver
        self.gt_layout = gt_layout
        self.gt_live = gt_live
        self.gt_budget = float(gt_budget)

        self.P = np.array(shape.P_moving, dtype=float)  # (n_moving,2) rest positions
        if len(self.P) == 0:
            raise ValueError(f"shape {shape.name!r} has no moving handle to drag")
        self.moving_idx = np.asarray(shape.moving_handles)
        self.fixed_idx = np.asarray(shape.fixed_handles)
        self.Q = self.P.copy()
        self.kind = basis
        self.X = np.array(self.mesh.V, dtype=float)
        self.X_gt = None
        self.Q_gt = None
        self.gt_enabled = False
        self.gt_stale = False
        self.gt_result = None
        self.gt_error = None
        self.gt_time = None
        self.active = None
        self.eval_time = 0.0
        self.fps = None
        self._last_frame = None
        self._syncing = False
        self._static_3d = None
        self._pv = None

        V = self.mesh.V
        lo, hi = V.min(axis=0), V.max(axis=0)
        self.diag = float(np.linalg.norm(hi - lo))
        self.pick_radius = float(pick_radius) * self.diag
        margin = 0.3 * self.diag
        self.xlim = (float(lo[0] - margin), float(hi[0] + margin))
        self.ylim = (float(lo[1] - margin), float(hi[1] + margin))

        self._build_figure(figsize)
        self._build_controls()
        self.get_operator(self.kind)  # train (or fetch) the first basis now, so errors surface here
        self.update(final=True)

    # ------------------------------------------------------------------ operators
    def _train(self, kind):
        kw = {
            "energy": self.energy,
            "basis": kind,
            "spatial": self.spatial,
            "seed": self.seed,
            "progress": False,
        }
        kw.update(self.train_kw)
        if "samples" not in kw:  # at least the fewest samples problem (8) needs for this basis and shape
            need = min_samples(kind, self.shape.n_moving)
            kw["m"] = max(self.m if self.m is not None else dop.train.DEFAULT_M, need)
        defop_, _record = dop.train.train(self.shape, **kw)
        return defop_

    def get_operator(self, kind):
        """The trained DefOp for handle basis ``kind`` (trained on first use).

        Parameters
        ----------
        kind : str
            One of :data:`BASES`.

        Returns
        -------
        DefOp
        """
        if kind not in BASES:
            raise ValueError(f"basis {kind!r} is unknown; choose one of {BASES}")
        if kind not in self.operators:
            self._set_status(f"training the {BASIS_LABELS[kind]} DefOp …")
            self.operators[kind] = self.trainer(kind)
        return self.operators[kind]

    @property
    def operator(self):
        """The DefOp of the current basis."""
        return self.get_operator(self.kind)

    # ------------------------------------------------------------------ figure
    def _build_figure(self, figsize):
        ncols = 2 if self.gt_layout == "beside" else 1
        if figsize is None:
            w = self.xlim[1] - self.xlim[0]
            h = self.ylim[1] - self.ylim[0]
            width = 7.0 if ncols == 1 else 9.0
            figsize = (width, float(np.clip(width / ncols * h / w + 0.6, 2.5, 6.0)))
        with plt.ioff():
            self.fig = plt.figure(figsize=figsize)
        canvas = self.fig.canvas
        for name, value in (
            ("header_visible", False),
            ("footer_visible", False),
            ("resizable", False),
        ):
            if hasattr(canvas, name):  # ipympl Canvas widget
                setattr(canvas, name, value)
        axes = self.fig.subplots(1, ncols, squeeze=False)[0]
        self.ax = axes[0]
        self.ax_gt = axes[1] if ncols == 2 else None
        F = self.mesh.F
        V = self.mesh.V
        for ax in axes:
            ax.set_xlim(*self.xlim)
            ax.set_ylim(*self.ylim)
            ax.set_aspect("equal", adjustable="box")
            ax.set_autoscale_on(False)
            ax.set_xticks([])
            ax.set_yticks([])
        self._mesh_artist = PolyCollection(V[F], facecolors=_FACE, edgecolors=_EDGE, linewidths=0.3)
        self.ax.add_collection(self._mesh_artist, autolim=False)
        gt_ax = self.ax_gt if self.ax_gt is not None else self.ax
        self._gt_artist = PolyCollection(
            V[F],
            facecolors=_FACE if self.ax_gt is not None else "none",
            edgecolors=(0.8, 0.1, 0.1, 0.7),
            linewidths=0.5,
            visible=False,
        )
        gt_ax.add_collection(self._gt_artist, autolim=False)
        (self._rest_artist,) = self.ax.plot(
            self.P[:, 0],
            self.P[:, 1],
            "o",
            ms=9,
            mfc="none",
            mec="0.55",
            mew=1.0,
            zorder=3,
        )
        Pf = self.mesh.V[self.fixed_idx] if len(self.fixed_idx) else np.zeros((0, 2))
        (self._fixed_artist,) = self.ax.plot(Pf[:, 0], Pf[:, 1], "s", ms=7, color="0.15", zorder=4)
        (self._handle_artist,) = self.ax.plot(
            self.Q[:, 0],
            self.Q[:, 1],
            "o",
            ms=9,
            color="C3",
            mec="k",
            mew=0.8,
            zorder=5,
        )
        (self._active_artist,) = self.ax.plot([], [], "o", ms=15, mfc="none", mec="C3", mew=2.0, zorder=6)
        self.ax.set_title(self._title(), fontsize=10)
        if self.ax_gt is not None:
            (self._gt_handle_artist,) = self.ax_gt.plot(
                self.Q[:, 0],
                self.Q[:, 1],
                "o",
                ms=7,
                color="C3",
                mec="k",
                mew=0.8,
                zorder=5,
            )
            self.ax_gt.set_title("ground truth (off)", fontsize=10)
        self.fig.tight_layout()
        self._cids = [
            canvas.mpl_connect("button_press_event", self._mpl_press),
            canvas.mpl_connect("motion_notify_event", self._mpl_motion),
            canvas.mpl_connect("button_release_event", self._mpl_release),
        ]

    def _title(self):
        size = getattr(getattr(self.operators.get(self.kind), "handle_basis", None), "size", None)
        psi = f", |Ψ| = {size}" if size is not None else ""
        return f"{self.shape.name}: {BASIS_LABELS[self.kind]} DefOp{psi} ({self.energy})"

    # ------------------------------------------------------------------ controls
    def _build_controls(self):
        self.basis_dropdown = widgets.Dropdown(
            options=[(BASIS_LABELS[k], k) for k in BASES],
            value=self.kind,
            description="Ψ basis",
            layout=widgets.Layout(width="200px"),
        )
        self.basis_dropdown.observe(self._on_widget(self.set_basis), names="value")
        self.gt_toggle = widgets.ToggleButton(value=False, description="Ground truth", icon="check")
        self.gt_toggle.observe(self._on_widget(self.set_ground_truth), names="value")
        self.solve_button = widgets.Button(description="Solve", tooltip="re-solve the ground truth now")
        self.solve_button.on_click(lambda _button: self.update_ground_truth())
        self.reset_button = widgets.Button(description="Reset", icon="undo", tooltip="back to the rest pose")
        self.reset_button.on_click(lambda _button: self.reset())
        self.readout = widgets.HTML()
        self.readout.add_class("defop-readout")
        self.handle_readout = widgets.HTML()
        self.handle_readout.add_class("defop-handles")
        self.sliders = []
        rows = []
        for i, (p, vid) in enumerate(zip(self.P, self.moving_idx, strict=True)):
            pair = []
            for c, (axis, lim) in enumerate((("x", self.xlim), ("y", self.ylim))):
                s = widgets.FloatSlider(
                    value=float(p[c]),
                    min=lim[0],
                    max=lim[1],
                    step=self.diag / 1000.0,
                    description=f"q{i} {axis}",
                    readout_format=".3f",
                    continuous_update=True,
                    layout=widgets.Layout(width="320px"),
                )
                s.observe(self._slider_callback(i, c), names="value")
                pair.append(s)
            self.sliders.append(tuple(pair))
            rows.append(widgets.HBox(pair + [widgets.Label(f"(vertex {int(vid)})")]))
        self.slider_box = widgets.VBox(rows)

    def _on_widget(self, method):
        def callback(change):
            if not self._syncing:
                method(change["new"])

        return callback

    def _set_widget(self, widget, value):
        """Set a control's value without re-entering the callbacks."""
        self._syncing = True
        try:
            widget.value = value
        finally:
            self._syncing = False

    def _slider_callback(self, i, c):
        def callback(change):
            if self._syncing:
                return
            Q = self.Q.copy()
            Q[i, c] = change["new"]
            self.set_Q(Q, _from_slider=True)

        return callback

    def _sync_sliders(self):
        self._syncing = True
        try:
            for (sx, sy), q in zip(self.sliders, self.Q, strict=True):
                sx.value = float(np.clip(q[0], sx.min, sx.max))
                sy.value = float(np.clip(q[1], sy.min, sy.max))
        finally:
            self._syncing = False

    @property
    def widget(self):
        """The whole editor as one ipywidget (controls, canvas, readouts, sliders)."""
        if getattr(self, "_widget", None) is None:
            canvas = self.fig.canvas
            if isinstance(canvas, widgets.DOMWidget):  # ipympl
                view = canvas
            else:  # a non-interactive backend: show a static picture
                view = widgets.Output()
                with view:
                    from IPython.display import display

                    display(self.fig)
            controls = widgets.HBox(
                [
                    self.basis_dropdown,
                    self.gt_toggle,
                    self.solve_button,
                    self.reset_button,
                ]
            )
            sliders = widgets.Accordion(children=[self.slider_box], titles=("Handle sliders",))
            sliders.selected_index = None
            self._widget = widgets.VBox([controls, view, self.readout, self.handle_readout, sliders])
        return self._widget

    def _ipython_display_(self):
        from IPython.display import display

        display(self.widget)

    # ------------------------------------------------------------------ matplotlib wiring
    def _event_data(self, event):
        if event.x is None or event.y is None:
            return None
        x, y = self.ax.transData.inverted().transform((event.x, event.y))
        return float(x), float(y)

    def _toolbar_busy(self):
        toolbar = getattr(self.fig.canvas, "toolbar", None)
        return bool(getattr(toolbar, "mode", ""))  # pan / zoom active

    def _mpl_press(self, event):
        if event.inaxes is not self.ax or event.button != 1 or self._toolbar_busy():
            return
        self.on_press(event.xdata, event.ydata)

    def _mpl_motion(self, event):
        if self.active is None:
            return
        xy = self._event_data(event)  # also valid outside the axes
        if xy is not None:
            self.on_motion(*xy)

    def _mpl_release(self, event):
        if self.active is None:
            return
        xy = self._event_data(event)
        self.on_release(*(xy or (None, None)))

    # ------------------------------------------------------------------ callbacks
    def pick(self, x, y):
        """Index of the moving handle nearest to (x, y) within the pick radius, else None."""
        if x is None or y is None:
            return None
        d = np.hypot(self.Q[:, 0] - x, self.Q[:, 1] - y)
        i = int(np.argmin(d))
        return i if d[i] <= self.pick_radius else None

    def on_press(self, x, y):
        """Start dragging the moving handle nearest to data point (x, y).

        Returns
        -------
        int or None
            The picked handle (index into the moving handles), None if no handle is near.
        """
        self.active = self.pick(x, y)
        self._last_frame = None
        if self.active is not None:
            q = self.Q[self.active]
            self._active_artist.set_data([q[0]], [q[1]])
            self.fig.canvas.draw_idle()
        return self.active

    def on_motion(self, x, y):
        """Move the dragged handle to (x, y) and re-evaluate D(·, Q). Returns True if something moved."""
        if self.active is None or x is None or y is None:
            return False
        if not (np.isfinite(x) and np.isfinite(y)):
            raise ValueError(f"handle position must be finite, got ({x}, {y})")
        self.Q[self.active] = (x, y)
        self.update(frame=True)
        self._sync_sliders()
        return True

    def on_release(self, x=None, y=None):
        """Finish a drag (optionally at (x, y)); refreshes the ground truth if it is on."""
        if self.active is None:
            return False
        if x is not None and y is not None:
            self.Q[self.active] = (x, y)
        self.active = None
        self._active_artist.set_data([], [])
        self.update(final=True)
        self._sync_sliders()
        return True

    def set_handle(self, i, q):
        """Move moving handle ``i`` to ``q`` (2,) and update."""
        if not 0 <= i < len(self.Q):
            raise ValueError(f"handle index {i} out of range 0..{len(self.Q) - 1}")
        Q = self.Q.copy()
        Q[i] = q
        self.set_Q(Q)

    def set_Q(self, Q, _from_slider=False):
        """Set all moving handles, ``Q (n_moving,2)``, and update the view."""
        Q = np.array(Q, dtype=float)
        if Q.shape != self.P.shape:
            raise ValueError(f"Q must have shape {self.P.shape} (moving handles), got {Q.shape}")
        bad = ~np.isfinite(Q).all(axis=1)
        if bad.any():
            raise ValueError(f"Q row {int(np.flatnonzero(bad)[0])} is not finite")
        self.Q = Q
        self.update(frame=_from_slider, final=not _from_slider)
        if not _from_slider:
            self._sync_sliders()

    def set_basis(self, kind):
        """Switch the handle basis Ψ (trains that DefOp on first use) and re-evaluate."""
        self.get_operator(kind)
        self.kind = kind
        self._set_widget(self.basis_dropdown, kind)
        self.update(final=True)

    def reset(self):
        """Back to the rest pose Q = P (also resets the ground truth warm start)."""
        self.active = None
        self._active_artist.set_data([], [])
        self.Q = self.P.copy()
        self.X_gt = None
        self.Q_gt = None
        self.fps = None
        self._last_frame = None
        self.update(final=True)
        self._sync_sliders()

    def set_ground_truth(self, enabled):
        """Show (and keep solving) the variational ground truth D^E_Φ(·, Q) next to the approximation."""
        self.gt_enabled = bool(enabled)
        self._set_widget(self.gt_toggle, self.gt_enabled)
        if not self.gt_enabled:
            self.gt_error = None
        self.update(final=True)

    # ------------------------------------------------------------------ evaluation
    def update(self, frame=False, final=False):
        """Evaluate D(·, Q), refresh artists and readouts, and ask the canvas to redraw.

        Parameters
        ----------
        frame : bool
            An interactive frame (drag / slider); counts towards the FPS readout.
        final : bool
            The end of an interaction; the ground truth (if on) is always re-solved.
        """
        op = self.operator
        t0 = time.perf_counter()
        X = np.asarray(op(self.Q))
        self.eval_time = time.perf_counter() - t0
        if X.shape != self.mesh.V.shape or not np.isfinite(X).all():
            raise ValueError(f"the {self.kind} DefOp returned an invalid deformation (shape {X.shape})")
        self.X = X
        if frame:
            now = time.perf_counter()
            if self._last_frame is not None:
                dt = now - self._last_frame
                if 0 < dt < 2.0:
                    self.fps = _ema(self.fps, 1.0 / dt)
            self._last_frame = now
        F = self.mesh.F
        self._mesh_artist.set_verts(X[F])
        self.flipped = np.asarray(self.mesh.flipped(X), dtype=bool)
        colors = np.tile(_FACE, (len(F), 1))
        colors[self.flipped] = _FACE_FLIPPED
        self._mesh_artist.set_facecolors(colors)
        self._handle_artist.set_data(self.Q[:, 0], self.Q[:, 1])
        if self.active is not None:
            q = self.Q[self.active]
            self._active_artist.set_data([q[0]], [q[1]])
        self.ax.set_title(self._title(), fontsize=10)
        if self.gt_enabled:
            live = self.gt_live is True or (
                self.gt_live == "auto" and (self.gt_time is None or self.gt_time < self.gt_budget)
            )
            if final or live:
                self.update_ground_truth(draw=False)
            else:
                self.gt_stale = True
        self._draw_ground_truth()
        self._refresh_readouts()
        if final and self._static_3d is not None:
            self._refresh_3d()
        if self._pv is not None:
            self._update_pyvista()
        self.fig.canvas.draw_idle()

    @property
    def solver(self):
        """The ground-truth solver (a :class:`defop.solve.Solver`, built on first use)."""
        if self._solver is None:
            self._set_status("factorising the ground-truth solver …")
            self._solver = dop.solve.Solver(self.mesh, self.shape.handles, energy=self.energy)
        return self._solver

    def update_ground_truth(self, draw=True):
        """Solve the variational DefOp at the current Q, warm-started from the previous frame.

        Warm starts tried in order:

        1. the previous ground truth moved by the approximation's step,
           ``X_gt(Q_prev) + D(·, Q) - D(·, Q_prev)``, which already meets the handle constraints
           because D interpolates the handles (8c);
        2. the current approximation D(·, Q);
        3. the solver's own robust start (None).

        :meth:`defop.solve.Solver.solve_best` with ``keep="first"`` (local, path following): the first
        start that reaches a verified minimum wins; flipped or rejected starts are skipped.

        Returns
        -------
        X_gt : (n_vertices,2) numpy array
        """
        targets = self.shape.targets(self.Q)
        starts = []
        if self.X_gt is not None:
            starts.append(self.X_gt + self.X - np.asarray(self.operator(self.Q_gt)))
        starts.append(self.X)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dop.solve.NotConvergedWarning)  # reported below
            result = self.solver.solve_best(targets, starts=starts, rest=True, keep="first")
        self.gt_time = time.perf_counter() - t0
        self.gt_result = result
        self.X_gt = np.asarray(result.X, dtype=float)
        self.Q_gt = self.Q.copy()
        self.gt_stale = False
        if not getattr(result, "converged", True):
            warnings.warn(
                f"ground-truth solve did not converge ({getattr(result, 'reason', '?')})",
                RuntimeWarning,
                stacklevel=2,
            )
        d = self.X - self.X_gt
        mass = np.asarray(self.mesh.mass_matrix.diagonal())
        rms = float(np.sqrt(np.sum(mass * np.sum(d * d, axis=1)) / np.sum(mass)))
        self.gt_error = {
            "rms": rms / self.diag,  # L2(Ω) distance / |Ω|^(1/2), relative to the bbox diagonal
            "max": float(np.max(np.linalg.norm(d, axis=1))) / self.diag,
            "flips_gt": int(np.sum(self.mesh.flipped(self.X_gt))),
        }
        if draw:
            self._draw_ground_truth()
            self._refresh_readouts()
            self.fig.canvas.draw_idle()
        return self.X_gt

    def _draw_ground_truth(self):
        show = self.gt_enabled and self.X_gt is not None
        self._gt_artist.set_visible(show)
        if show:
            self._gt_artist.set_verts(self.X_gt[self.mesh.F])
        if self.ax_gt is not None:
            Qg = self.Q_gt if (show and self.Q_gt is not None) else np.zeros((0, 2))
            self._gt_handle_artist.set_data(Qg[:, 0], Qg[:, 1])
            state = "stale" if self.gt_stale else "current"
            self.ax_gt.set_title(f"ground truth ({state})" if show else "ground truth (off)", fontsize=10)

    # ------------------------------------------------------------------ readouts
    def _set_status(self, text):
        if hasattr(self, "readout"):
            self.readout.value = f"<span>{html.escape(text)}</span>"

    def handle_canvas_fractions(self):
        """Positions of the moving handles on the canvas as fractions of its width/height from the top left.

        Returns
        -------
        (n_moving,2) numpy array
            ``(u, v)`` in [0,1]²; pixel = (u·width, v·height) of the displayed canvas, whatever its
            device-pixel ratio. Used by the browser test to find where to drag.
        """
        self.ax.apply_aspect()
        disp = self.ax.transData.transform(self.Q)
        w, h = self.fig.bbox.width, self.fig.bbox.height
        return np.column_stack([disp[:, 0] / w, 1.0 - disp[:, 1] / h])

    def readout_text(self):
        """One-line summary: basis, evaluation time, FPS, flips and (if on) the ground-truth error."""
        parts = [f"{BASIS_LABELS[self.kind]}: evaluation {self.eval_time * 1e3:.2f} ms"]
        if self.eval_time > 0:
            parts[0] += f" ({1.0 / self.eval_time:,.0f} evaluations/s)"
        parts.append(f"{self.fps:.0f} fps" if self.fps is not None else "– fps")
        parts.append(f"flipped triangles: {int(np.sum(self.flipped))}")
        if self.gt_enabled:
            if self.gt_error is None:
                parts.append("ground truth: not solved yet")
            else:
                e = self.gt_error
                stale = " (stale: release the mouse or press Solve)" if self.gt_stale else ""
                if not getattr(self.gt_result, "converged", True):
                    stale += " (solver NOT converged)"
                parts.append(
                    f"ground truth ({self.gt_time * 1e3:.0f} ms, {e['flips_gt']} flips): "
                    f"error rms {100 * e['rms']:.2f}% / max {100 * e['max']:.2f}% of the diagonal{stale}"
                )
        return " · ".join(parts)

    def _refresh_readouts(self):
        self.readout.value = f"<span>{html.escape(self.readout_text())}</span>"
        Q = np.round(self.Q, 6).tolist()
        uv = np.round(self.handle_canvas_fractions(), 6).tolist()
        text = ", ".join(f"q{i} = ({q[0]:.3f}, {q[1]:.3f})" for i, q in enumerate(Q))
        self.handle_readout.value = (
            f"<span class='defop-handle-data' data-q='{json.dumps(Q)}' data-uv='{json.dumps(uv)}'>"
            f"{html.escape(text)}</span>"
        )

    # ------------------------------------------------------------------ 3D view
    def view_3d(self, backend=None):
        """A PyVista view of the current deformation (flat mesh in 3D, coloured by area distortion).

        Parameters
        ----------
        backend : {"trame", "static", None}
            ``"trame"``: live, interactive (needs the ``trame`` packages); ``"static"``: a PNG
            rendered with :func:`defop.render.render_mesh`, refreshed at the end of each
            interaction. None picks trame when importable.

        Returns
        -------
        ipywidgets widget
        """
        if backend is None:
            backend = "trame" if find_spec("trame") is not None and find_spec("trame_vtk") is not None else "static"
        if backend == "trame":
            import pyvista as pv

            dop.render.configure_headless()
            points = np.column_stack([self.X, np.zeros(len(self.X))])
            faces = np.column_stack([np.full(len(self.mesh.F), 3), self.mesh.F]).ravel()
            poly = pv.PolyData(points, faces)
            plotter = pv.Plotter(notebook=True)
            plotter.add_mesh(poly, color="lightsteelblue", show_edges=True)
            plotter.view_xy()
            self._pv = (plotter, poly)
            return plotter.show(jupyter_backend="trame", return_viewer=True)
        if backend != "static":
            raise ValueError(f"backend must be 'trame', 'static' or None, got {backend!r}")
        self._static_3d = widgets.Image(format="png")
        self._refresh_3d()
        return self._static_3d

    def _update_pyvista(self):
        plotter, poly = self._pv
        poly.points[:, :2] = self.X
        plotter.render()

    def _refresh_3d(self):
        image = np.asarray(
            dop.render.render_mesh(self.mesh, self.X, handles=self.shape.handles, moving=self.shape.moving)
        )
        buffer = io.BytesIO()
        plt.imsave(buffer, image, format="png")
        self._static_3d.value = buffer.getvalue()

    # ------------------------------------------------------------------ teardown
    def close(self):
        """Disconnect the events and close the figure."""
        for cid in self._cids:
            self.fig.canvas.mpl_disconnect(cid)
        self._cids = []
        plt.close(self.fig)


def min_samples(kind, n_moving):
    """The fewest training samples Q_k (rest pose not counted) problem (8) accepts for a basis.

    Parameters
    ----------
    kind : str
        One of :data:`BASES`.
    n_moving : int
        Moving handles of the shape.

    Returns
    -------
    m : int
        TPS: 2n + 1 (its linear part plus one centre); a polynomial Ψ: |Ψ| - 1
        (:func:`defop.handle_bases.basis_size`), so that the fit is determined.
    """
    if kind == "tps":
        return 2 * n_moving + 1
    return dop.handle_bases.basis_size(kind, n_moving) - 1


def static_bundle(editor, dpi=72):
    """A picture of the editor's canvas and one line of text: what a stored notebook shows without a kernel.

    Parameters
    ----------
    editor : HandleEditor
    dpi : int

    Returns
    -------
    bundle : dict
        ``{"image/png": base64 str, "text/plain": str}``.
    """
    import base64

    buf = io.BytesIO()
    editor.fig.savefig(buf, format="png", dpi=dpi)
    shape = editor.shape
    text = (
        f"Handle editor: {shape.name}, {shape.mesh.n_vertices} vertices, {len(editor.P)} moving handle(s), "
        f"the {BASIS_LABELS[editor.kind]} DefOp (run the notebook to drag the handles)"
    )
    return {"image/png": base64.b64encode(buf.getvalue()).decode("ascii"), "text/plain": text}


class _PickerBox(widgets.VBox):
    """The picker's box; a stored notebook keeps a picture of the editor instead of a raw widget repr."""

    editor = None

    def _repr_mimebundle_(self, **kwargs):
        bundle = super()._repr_mimebundle_(**kwargs) or {}
        if self.editor is not None:
            bundle.update(static_bundle(self.editor))
        return bundle


class _WidgetBar:
    """A progress bar on an ipywidgets IntProgress, with the interface ``train`` expects (update, close)."""

    def __init__(self, bar, label, total, desc):
        self.bar, self.label, self.desc = bar, label, desc
        bar.max, bar.value = max(int(total), 1), 0
        bar.layout.display = None
        self._show()

    def _show(self):
        self.label.value = f"{self.desc}: {self.bar.value} of {self.bar.max}"

    def update(self, n=1):
        self.bar.value = min(self.bar.value + int(n), self.bar.max)
        self._show()

    def close(self):
        self.bar.layout.display = "none"


def shape_picker(names=None, value="bar", **editor_kw):
    """A dropdown of shapes; choosing one builds a :class:`HandleEditor` for it (training on first use).

    Parameters
    ----------
    names : list of str, optional
        Shapes to offer (default: :func:`defop.shapes.names`).
    value : str
        The shape shown first.
    **editor_kw
        Passed to :class:`HandleEditor`; each basis trains with at least :func:`min_samples`
        samples, and a progress bar under the dropdown follows the sample solves.

    Returns
    -------
    box : ipywidgets.VBox
        ``box.editor`` is the current editor. Displayed without a live kernel (a stored notebook),
        it shows a picture of the editor and one line of text.
    """
    from IPython.display import display

    names = list(names) if names is not None else list(dop.shapes.names())
    if value not in names:
        raise ValueError(f"shape {value!r} is not among {names}")
    dropdown = widgets.Dropdown(options=names, value=value, description="Shape")
    label = widgets.Label()
    bar = widgets.IntProgress(layout=widgets.Layout(display="none", width="240px"))
    out = widgets.Output()
    box = _PickerBox([dropdown, widgets.HBox([label, bar]), out])
    train_kw = dict(editor_kw.pop("train_kw", None) or {})
    train_kw.setdefault("progress", lambda total, desc: _WidgetBar(bar, label, total, desc))

    def show(name):
        if box.editor is not None:
            box.editor.close()
        out.clear_output()
        label.value = f"preparing {name} …"
        try:
            editor = HandleEditor(name, train_kw=train_kw, **editor_kw)
        except Exception as exc:
            label.value = f"could not prepare {name}: {exc}"
            raise
        label.value = ""
        with out:
            display(editor)
        box.editor = editor

    dropdown.observe(lambda change: show(change["new"]), names="value")
    show(value)
    return box
