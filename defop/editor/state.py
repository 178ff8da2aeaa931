"""The handle editor's state, without any view: Q, X, the operators per basis and the ground truth.

This is the pure part of the interactive editor: a view (the in-page editor of
:mod:`defop.editor.browser`, or a matplotlib figure) draws it and calls its methods; tests drive the same
methods. Nothing here imports matplotlib, ipywidgets or anywidget.

The editor is split in two: this module holds the state (:class:`EditorState`, its setters and the readout), and
:mod:`defop.editor.logic` the logic as pure functions (argument checks, the region tests, training a basis on first
use, the distance to the ground truth, the restore of a rejected call), which stay importable from here.

Example
-------
>>> state = EditorState("bar", m=40)                 # doctest: +SKIP
>>> state.set_handle(0, state.P[0] + [0.1, 0.2])      # doctest: +SKIP
>>> state.press(*state.Q[0]); state.drag(1.0, 0.3); state.release()   # what a pointer does  # doctest: +SKIP
>>> state.outside_regions()                           # doctest: +SKIP
>>> state.set_ground_truth(True); state.gt_error      # doctest: +SKIP
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .. import options as opt
from ..operator.core import EXTRAPOLATION_FACTOR
from ..operator.defop import ExtrapolationWarning, check_mesh
from ..operator.handle_bases import KINDS
from ..variational.solver import NotConvergedWarning, Solver
from . import rest as rest_mode
from .logic import (
    STATE,
    check_flag,
    check_index,
    check_Q,
    check_shape,
    extrapolating,
    ground_truth_error,
    inside_polygon,
    reach_polygons,
    region_polygons,
    restoring,
    train_operator,
)

#: the pure functions' home is :mod:`.logic` (the split of the editor: logic there, state here); importable from here
__all__ = [
    "EditorState",
    "ground_truth_error",
    "ground_truth_text",
    "inside_polygon",
    "reach_polygons",
    "readout_text",
    "region_polygons",
]


class EditorState:
    """Moving handles Q, the deformation X = D(·, Q) and the ground truth of one shape.

    The views (:mod:`defop.editor.browser`, :mod:`defop.editor.widgets`) draw it and call its methods, as the tests do.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape or str
        The shape (a name is loaded with :func:`defop.scene.shapes.load`).
    operators : dict, optional
        Trained DefOps by basis kind; missing kinds are trained on first use.
    basis : str
        The initial handle basis Ψ.
    energy : str
        Energy of the operators and of the ground-truth solve.
    m : int, optional
        Training samples Q_k; raised to :func:`defop.training.bootstrap.min_samples` of the basis and the shape's moving
        handles (so every shape trains), :data:`defop.training.bootstrap.DEFAULT_M` when None.
    kinds : sequence of str
        The bases offered.
    trainer : callable, optional
        ``trainer(shape, kind) -> DefOp``; default :func:`defop.training.bootstrap.train` with ``m`` and ``train_kw``.
    solver : object, optional
        Ground-truth solver with :meth:`~defop.variational.solver.Solver.solve_best`'s signature, returning a
        result with
        ``X`` and ``converged``; default a :class:`defop.variational.solver.Solver` built on first use.
    pick_radius : float
        Picking distance as a fraction of the bounding-box diagonal.
    train_kw : dict, optional
        Extra keyword arguments of :func:`defop.training.bootstrap.train` (``spatial``, ``seed``, ``progress``, ...).

    Attributes
    ----------
    P : (n,2) numpy array
        Rest positions of the moving handles.
    Q : (n,2) numpy array
        Current positions of the moving handles.
    X : (n_vertices,2) numpy array
        D(·, Q) of the current basis.
    active : int or None
        The handle being dragged (:meth:`press` / :meth:`drag` / :meth:`release`).
    eval_time : float
        Seconds of the last evaluation of D(·, Q).
    flipped : (m,) bool numpy array
        The triangles D(·, Q) flips (det J ≤ 0).
    X_gt : (n_vertices,2) numpy array or None
        The last ground truth D^E(·, Q_gt), None when off or not solved yet.
    gt_error : dict or None
        :func:`ground_truth_error` of the last ground truth.
    """

    def __init__(
        self,
        shape,
        operators=None,
        *,
        basis="tps",
        energy="sarap",
        m=None,
        kinds=KINDS,
        trainer=None,
        solver=None,
        pick_radius=0.05,
        train_kw=None,
    ):
        shape = check_shape(shape)
        self.kinds = tuple(kinds)
        for kind in [basis, *(operators or {})]:
            if kind not in self.kinds:
                raise ValueError(f"basis {kind!r} is not offered; choose one of {self.kinds}")
        pick_radius = opt.positive("pick_radius", pick_radius)
        if m is not None:
            m = opt.integer("m", m, minimum=1)
        self.shape, self.mesh, self.energy, self.m = shape, shape.mesh, energy, m
        self.train_kw = dict(train_kw or {})
        self.operators = dict(operators or {})
        for op in self.operators.values():
            check_mesh(op, self.mesh)
        self.trainer = trainer
        self._solver = solver
        self.P = np.array(shape.P_moving, dtype=float)
        self.diag = float(self.mesh.bbox_diagonal)
        self.pick_radius = float(pick_radius)
        self.regions = region_polygons(self.P, shape.regions)
        self.kind = basis
        self.gt_enabled = False
        self.active, self.eval_time = None, 0.0
        self.get_operator(basis)
        rest_mode.init_rest(self)  # a MovableOp: the rest mode (defop.editor.rest)
        self.reset()

    # ------------------------------------------------------------------ operators
    def get_operator(self, kind):
        """The DefOp of basis ``kind`` (trained on first use, with at least the samples the basis needs).

        Returns
        -------
        defop.operator.DefOp
        """
        if kind not in self.kinds:
            raise ValueError(f"basis {kind!r} is not offered; choose one of {self.kinds}")
        if kind not in self.operators:
            if self.trainer is not None:
                op = self.trainer(self.shape, kind)
            else:
                op = train_operator(self.shape, kind, self.energy, self.m, self.train_kw)
            check_mesh(op, self.mesh)
            self.operators[kind] = op
        return self.operators[kind]

    @property
    def operator(self):
        """The DefOp of the current basis."""
        return self.get_operator(self.kind)

    def _atomic(self):
        """Every setter runs inside this (:func:`.logic.restoring`): it validates first, and whatever fails later (an
        operator that returns NaN, a solver error) restores :data:`.logic.STATE`, so a rejected call changes nothing."""
        return restoring(self, STATE)

    def set_basis(self, kind):
        """Switch the handle basis Ψ (training it on first use) and re-evaluate at the same Q."""
        self.get_operator(kind)
        with self._atomic():
            self.kind = kind
            self._evaluate()
            if self.gt_enabled:
                self.update_ground_truth()

    # ------------------------------------------------------------------ handles
    def set_Q(self, Q):
        """Move all moving handles to ``Q (n,2)`` and re-evaluate (the ground truth too, when on)."""
        Q = check_Q(Q, self.P)
        with self._atomic():
            self._move(Q)
            if self.gt_enabled:
                self.update_ground_truth()

    def _move(self, Q):
        self.Q = check_Q(Q, self.P)
        self._evaluate()

    def set_handle(self, i, q):
        """Move moving handle ``i`` to ``q (2,)`` and re-evaluate (a scalar ``q`` is refused, not broadcast)."""
        i = check_index(i, len(self.P))
        Q = self.Q.copy()
        Q[i] = opt.point("q", q)
        self.set_Q(Q)

    def reset(self):
        """Back to the rest pose Q = P; forgets the ground truth's warm start."""
        with self._atomic():
            self.X_gt = self.Q_gt = self.gt_result = self.gt_error = self.gt_time = None
            self.active = None
            self.set_Q(self.P)

    def set_rest_mode(self, enabled):
        """Turn the rest mode on or off (:func:`defop.editor.rest.set_rest_mode`): a press moves a rest handle."""
        rest_mode.set_rest_mode(self, enabled)

    def set_rest(self, ell, target):
        """Move movable handle ``ell``'s rest position to a vertex or point (:func:`defop.editor.rest.set_rest`)."""
        rest_mode.set_rest(self, ell, target)

    def pick(self, x, y):
        """The moving handle nearest to (x, y) within ``pick_radius`` × diagonal, else None."""
        x, y = opt.point("(x, y)", (x, y))
        d = np.hypot(self.Q[:, 0] - x, self.Q[:, 1] - y)
        i = int(np.argmin(d))
        return i if d[i] <= self.pick_radius * self.diag else None

    # ------------------------------------------------------------------ a drag (what a pointer does)
    def press(self, x, y, shift=False):
        """Start dragging the handle nearest to (x, y); returns its index, or None when none is near. In the rest
        mode, or with ``shift``, a rest handle (:func:`defop.editor.rest.press_rest`)."""
        if self.rest is not None and (self.rest_mode or check_flag("shift", shift)):
            return rest_mode.press_rest(self, x, y)
        self.active = self.pick(x, y)
        return self.active

    def drag(self, x, y):
        """Move the dragged handle to (x, y): D(·, Q) only, the ground truth waits for :meth:`release`.

        Returns
        -------
        bool
            False when no handle is being dragged.
        """
        xy = opt.point("(x, y)", (x, y))
        if self.rest_active is not None:
            rest_mode.drag_rest(self, *xy)
            return True
        if self.active is None:
            return False
        Q = self.Q.copy()
        Q[self.active] = xy
        with self._atomic():
            self._move(Q)
        return True

    def release(self, x=None, y=None):
        """End the drag (at (x, y) when given) and refresh the ground truth when it is on."""
        if (x is None) != (y is None):
            raise ValueError(f"x and y go together: both or neither, got x={x!r}, y={y!r}")
        xy = None if x is None else opt.point("(x, y)", (x, y))
        if self.rest_active is not None:
            return rest_mode.release_rest(self, xy)
        if self.active is None:
            return False
        Q = self.Q.copy()
        if xy is not None:
            Q[self.active] = xy
        with self._atomic():
            self.active = None
            self.set_Q(Q)
        return True

    def outside_regions(self, Q=None):
        """Indices of the moving handles where the operator extrapolates: beyond
        :data:`~defop.operator.core.EXTRAPOLATION_FACTOR` times their farthest training sample, the rule of its
        ExtrapolationWarning and of the page (:func:`.logic.extrapolating`).

        Parameters
        ----------
        Q : (n,2) numpy array, optional
            Default: the current Q.

        Returns
        -------
        list of int
        """
        Q = self.Q if Q is None else opt.points("Q", Q, n=len(self.P))
        op = self.operator
        if hasattr(op, "train_samples"):
            return extrapolating(Q, self.P, op.train_samples)
        return extrapolating(Q, self.P, None, reach=getattr(op, "reach", None))  # a MovableOp: its reach of Q - P

    def _evaluate(self):
        t0 = time.perf_counter()
        with warnings.catch_warnings():  # the readout reports extrapolation through outside_regions
            warnings.simplefilter("ignore", ExtrapolationWarning)
            X = np.asarray(rest_mode.frame(self), dtype=float)
        self.eval_time = time.perf_counter() - t0
        if X.shape != self.mesh.V.shape or not np.isfinite(X).all():
            raise ValueError(f"the {self.kind} DefOp returned an invalid deformation (shape {X.shape})")
        self.X = X
        self.flipped = np.asarray(self.mesh.flipped(X), dtype=bool)  # (m,) the triangles D(·, Q) flips

    # ------------------------------------------------------------------ ground truth
    @property
    def solver(self):
        """The ground-truth solver (a :class:`defop.variational.solver.Solver`, built on first use)."""
        if self._solver is None:
            self._solver = Solver(self.mesh, self.shape.handles, energy=self.energy)
        return self._solver

    def set_ground_truth(self, enabled):
        """Turn the ground truth on (solving it at the current Q) or off (``enabled``: True or False)."""
        enabled = check_flag("enabled", enabled)
        with self._atomic():
            self.gt_enabled = enabled
            if self.gt_enabled:
                self.update_ground_truth()
            else:
                self.gt_error = None

    def update_ground_truth(self):
        """Solve the variational DefOp (problem 6) at Q, warm-started, and measure the approximation's error.

        The one warm-start policy of the editor: :meth:`defop.variational.solver.Solver.solve_best` with
        ``keep="first"``
        (local, path following) over the starts, in order: the previous ground truth moved by the
        approximation's step ``X_gt + D(·, Q) − D(·, Q_gt)`` (it meets the handle constraints because D
        interpolates them, Prop. 2), then D(·, Q), then the rest pose. The first start that reaches a
        verified minimum wins; flipped or rejected starts are skipped.

        Returns
        -------
        X_gt : (n_vertices,2) numpy array
        """
        with self._atomic():
            return self._solve_ground_truth()

    def _solve_ground_truth(self):
        starts = []
        if self.X_gt is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)
                starts.append(self.X_gt + self.X - np.asarray(rest_mode.frame(self, self.Q_gt)))
        starts.append(self.X)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotConvergedWarning)  # the readout reports it
            result = self.solver.solve_best(self.shape.targets(self.Q), starts=starts, rest=True, keep="first")
        self.gt_time = time.perf_counter() - t0
        self.gt_result = result
        self.X_gt, self.Q_gt = np.asarray(result.X, dtype=float), self.Q.copy()
        self.gt_error = ground_truth_error(self.mesh, self.X, self.X_gt)
        return self.X_gt


def ground_truth_text(state):
    """One line for the readout: solve time, convergence, flips and the error (or an empty string).

    Parameters
    ----------
    state : EditorState

    Returns
    -------
    str
    """
    if not state.gt_enabled or state.gt_error is None:
        return ""
    e = state.gt_error
    conv = "" if getattr(state.gt_result, "converged", True) else " (solver NOT converged)"
    return (
        f"ground truth: {1e3 * state.gt_time:.0f} ms{conv}, {e['flips_gt']} flips; error rms "
        f"{100 * e['rms']:.2f}% / max {100 * e['max']:.2f}% of the diagonal"
    )


def readout_text(state):
    """One line (str) of an :class:`EditorState`: basis, evaluation time, flips, extrapolating handles and (when on)
    the ground truth (:func:`ground_truth_text`)."""
    parts = [
        f"{state.kind}: evaluation {1e3 * state.eval_time:.2f} ms",
        f"flipped triangles: {int(state.flipped.sum())}",
    ]
    outside = state.outside_regions()
    if outside:
        parts.append(
            f"handle {', '.join(map(str, outside))} beyond {EXTRAPOLATION_FACTOR:g}x its farthest training sample "
            "(extrapolation)"
        )
    return " · ".join([*parts, ground_truth_text(state)] if state.gt_enabled else parts)
