"""The handle editor's state, without any view: Q, X, the operators per basis and the ground truth.

This is the pure part of the interactive editor (issue #18): a view (the in-page editor of
:mod:`defop.editor.browser`, or a matplotlib figure) draws it and calls its methods; tests drive the same
methods. Nothing here imports matplotlib, ipywidgets or anywidget.

Example
-------
>>> state = EditorState("bar", m=40)                 # doctest: +SKIP
>>> state.set_handle(0, state.P[0] + [0.1, 0.2])      # doctest: +SKIP
>>> state.press(*state.Q[0]); state.drag(1.0, 0.3); state.release()   # what a pointer does  # doctest: +SKIP
>>> state.outside_regions()                           # doctest: +SKIP
>>> state.set_ground_truth(True); state.gt_error      # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import numbers
import time
import warnings

import numpy as np

from .. import options as opt
from ..operator.defop import ExtrapolationWarning
from ..operator.handle_bases import KINDS
from ..scene.shapes import Shape
from ..scene.shapes import load as load_shape
from ..training.bootstrap import DEFAULT_M, min_samples, train
from ..variational.solver import NotConvergedWarning, Solver


def region_polygons(P, regions, n=96):
    """The sampling region of every moving handle as closed polygons (§3.3).

    A handle is inside its region when it is inside any of its polygons: for a Gaussian region that is
    the 2σ circle, for a mixture the union of its components.

    Parameters
    ----------
    P : (n,2) numpy array
        Rest positions of the moving handles.
    regions : list of dict
        One region per moving handle, as in :class:`defop.scene.shapes.Shape`.
    n : int
        Points per circle.

    Returns
    -------
    polygons : list of list of (k,2) numpy array
    """
    from ..view.plot import region_outlines  # numpy only; plot.py is where the region outlines are defined today

    P = np.asarray(P, float)
    return [[poly for poly, _style in region_outlines(c, r, P, i, n) if len(poly) >= 3] for i, (c, r) in
            enumerate(zip(P, regions, strict=True))]


def reach_polygons(P, samples, n=96):
    """Discs through the farthest training sample of each moving handle (when no regions are known).

    Parameters
    ----------
    P : (n,2) numpy array
    samples : (m,n,2) numpy array or None

    Returns
    -------
    polygons : list of list of (k,2) numpy array
        Empty lists when there are no samples.
    """
    P = np.asarray(P, float)
    if samples is None or len(samples) < 2:
        return [[] for _ in P]
    reach = np.linalg.norm(np.asarray(samples, float) - P, axis=-1).max(axis=0)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    unit = np.column_stack([np.cos(t), np.sin(t)])
    return [[p + r * unit] for p, r in zip(P, reach)]


def inside_polygon(q, poly):
    """Even-odd point-in-polygon test (the same rule as ``insidePolygon`` in the page).

    Parameters
    ----------
    q : (2,) numpy array
    poly : (k,2) numpy array

    Returns
    -------
    bool
    """
    x, y = opt.point("q", q)
    poly = opt.points("poly", poly)
    xi, yi = poly[:, 0], poly[:, 1]
    xj, yj = np.roll(xi, 1), np.roll(yi, 1)
    crosses = (yi > y) != (yj > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = (xj - xi) * (y - yi) / (yj - yi) + xi
    return bool(np.count_nonzero(crosses & (x < xs)) % 2)


def ground_truth_error(mesh, X, X_gt):
    """Distance between the approximation and the ground truth, relative to the bounding-box diagonal.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X, X_gt : (n,2) numpy array

    Returns
    -------
    dict
        ``rms``: the L2(Ω) distance / |Ω|^½ (lumped mass), ``max``: the largest vertex distance, both
        divided by the diagonal; ``flips_gt``: flipped triangles of the ground truth.
    """
    d = np.asarray(X, float) - np.asarray(X_gt, float)
    mass = np.asarray(mesh.mass_matrix.diagonal())
    diag = mesh.bbox_diagonal
    rms = float(np.sqrt(np.sum(mass * np.sum(d * d, axis=1)) / np.sum(mass)))
    return {
        "rms": rms / diag,
        "max": float(np.max(np.linalg.norm(d, axis=1))) / diag,
        "flips_gt": int(np.sum(mesh.flipped(X_gt))),
    }


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

    def __init__(self, shape, operators=None, *, basis="tps", energy="sarap", m=None, kinds=KINDS, trainer=None,
                 solver=None, pick_radius=0.05, train_kw=None):
        if isinstance(shape, str):
            shape = load_shape(shape)
        elif not isinstance(shape, Shape):
            raise ValueError(f"shape must be a Shape or the name of one (dop.shapes.names()), got "
                             f"{type(shape).__name__} {shape!r:.80}")
        if shape.mesh.dim != 2:
            raise ValueError(f"shape must be a 2D shape for the editor (drags in the plane), got the {shape.mesh.dim}D "
                             f"shape {shape.name!r}: write the 3D page instead, defop.editor.to_html(op, path, "
                             f"shape=shape), and show it with IPython.display.IFrame(path)")
        self.kinds = tuple(kinds)
        for kind in [basis, *(operators or {})]:
            if kind not in self.kinds:
                raise ValueError(f"basis {kind!r} is not offered; choose one of {self.kinds}")
        pick_radius = opt.positive("pick_radius", pick_radius)
        if m is not None:
            m = opt.integer("m", m, minimum=1)
        if shape.n_moving == 0:
            raise ValueError(f"shape {shape.name!r} has no moving handle to drag")
        self.shape, self.mesh, self.energy, self.m = shape, shape.mesh, energy, m
        self.train_kw = dict(train_kw or {})
        self.operators = dict(operators or {})
        for op in self.operators.values():
            op.check_mesh(self.mesh)
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
                kw = {"energy": self.energy, "basis": kind, "progress": False, **self.train_kw}
                if "samples" not in kw:
                    m = DEFAULT_M if self.m is None else int(self.m)
                    kw["m"] = max(m, min_samples(kind, self.shape.n_moving))
                op, _record = train(self.shape, **kw)
            op.check_mesh(self.mesh)
            self.operators[kind] = op
        return self.operators[kind]

    @property
    def operator(self):
        """The DefOp of the current basis."""
        return self.get_operator(self.kind)

    # every setter below runs inside _atomic: it validates first, and whatever fails later (an operator that
    # returns NaN, a solver error) restores the state as it was, so a rejected call changes nothing
    _STATE = ("Q", "X", "flipped", "eval_time", "kind", "gt_enabled", "X_gt", "Q_gt", "gt_result", "gt_error",
              "gt_time", "active")

    @contextlib.contextmanager
    def _atomic(self):
        saved = {name: getattr(self, name, None) for name in self._STATE}
        try:
            yield
        except BaseException:
            for name, value in saved.items():
                setattr(self, name, value)
            raise

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
        Q = self._check_Q(Q)
        with self._atomic():
            self._move(Q)
            if self.gt_enabled:
                self.update_ground_truth()

    def _check_Q(self, Q):
        Q = opt.real_array("Q", Q)
        if Q.shape != self.P.shape:
            raise ValueError(f"Q must have shape {self.P.shape} (the moving handles), got {Q.shape}")
        bad = ~np.isfinite(Q).all(axis=1)
        if bad.any():
            raise ValueError(f"handle {int(np.flatnonzero(bad)[0])} has a NaN or infinite position")
        return np.array(Q, dtype=float)

    def _move(self, Q):
        self.Q = self._check_Q(Q)
        self._evaluate()

    def _check_index(self, i):
        i = opt.integer("handle index", i)  # 1.5 was truncated to 1
        if not 0 <= i < len(self.P):
            raise ValueError(f"handle index {i} is out of range 0..{len(self.P) - 1}")
        return i

    def set_handle(self, i, q):
        """Move moving handle ``i`` to ``q (2,)`` and re-evaluate (a scalar ``q`` is refused, not broadcast)."""
        i = self._check_index(i)
        Q = self.Q.copy()
        Q[i] = opt.point("q", q)
        self.set_Q(Q)

    def reset(self):
        """Back to the rest pose Q = P; forgets the ground truth's warm start."""
        with self._atomic():
            self.X_gt = self.Q_gt = self.gt_result = self.gt_error = self.gt_time = None
            self.active = None
            self.set_Q(self.P)

    def pick(self, x, y):
        """The moving handle nearest to (x, y) within ``pick_radius`` × diagonal, else None."""
        x, y = opt.point("(x, y)", (x, y))
        d = np.hypot(self.Q[:, 0] - x, self.Q[:, 1] - y)
        i = int(np.argmin(d))
        return i if d[i] <= self.pick_radius * self.diag else None

    # ------------------------------------------------------------------ a drag (what a pointer does)
    def press(self, x, y):
        """Start dragging the handle nearest to (x, y); returns its index, or None when none is near."""
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
        """Indices of the moving handles outside their sampling region (the operator extrapolates there).

        Parameters
        ----------
        Q : (n,2) numpy array, optional
            Default: the current Q.

        Returns
        -------
        list of int
        """
        Q = self.Q if Q is None else opt.points("Q", Q, n=len(self.P))
        return [i for i, polys in enumerate(self.regions) if polys and not any(inside_polygon(Q[i], p) for p in polys)]

    def _evaluate(self):
        t0 = time.perf_counter()
        with warnings.catch_warnings():  # the readout reports extrapolation through outside_regions
            warnings.simplefilter("ignore", ExtrapolationWarning)
            X = np.asarray(self.operator(self.Q), dtype=float)
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
        if not isinstance(enabled, (bool, np.bool_)) and not (
                isinstance(enabled, numbers.Integral) and enabled in (0, 1)):
            raise ValueError(f"enabled must be True or False, got {enabled!r}")  # bool("off") is True
        with self._atomic():
            self.gt_enabled = bool(enabled)
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
                starts.append(self.X_gt + self.X - np.asarray(self.operator(self.Q_gt)))
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
    return (f"ground truth: {1e3 * state.gt_time:.0f} ms{conv}, {e['flips_gt']} flips; error rms "
            f"{100 * e['rms']:.2f}% / max {100 * e['max']:.2f}% of the diagonal")


def readout_text(state):
    """One line: basis, evaluation time, flips, extrapolating handles and (when on) the ground truth.

    Parameters
    ----------
    state : EditorState

    Returns
    -------
    str
    """
    parts = [f"{state.kind}: evaluation {1e3 * state.eval_time:.2f} ms",
             f"flipped triangles: {int(state.flipped.sum())}"]
    outside = state.outside_regions()
    if outside:
        parts.append(f"handle {', '.join(map(str, outside))} outside its sampling region (extrapolation)")
    return " · ".join([*parts, ground_truth_text(state)] if state.gt_enabled else parts)
