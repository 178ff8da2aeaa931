"""The editor's logic as pure functions on arrays: the checks of its arguments, the sampling-region tests, the
training of a basis on first use and the distance to the ground truth.

:class:`defop.editor.state.EditorState` holds the state (Q, X, the operators, the ground truth) and calls these;
they read no state of their own, so tests and the views can call them directly. Nothing here imports matplotlib,
ipywidgets or anywidget (the region outlines of :mod:`defop.view.plot` are numpy only).
"""

from __future__ import annotations

import contextlib
import numbers

import numpy as np

from .. import options as opt
from ..operator.core import beyond_reach
from ..operator.defop import training_reach
from ..scene.shapes import Shape
from ..scene.shapes import load as load_shape
from ..training.bootstrap import defaults, min_samples, train

#: what a rejected :class:`~defop.editor.state.EditorState` call restores (:func:`restoring`)
STATE = (
    "Q",
    "X",
    "flipped",
    "eval_time",
    "kind",
    "gt_enabled",
    "X_gt",
    "Q_gt",
    "gt_result",
    "gt_error",
    "gt_time",
    "active",
    "shape",
    "P",
    "regions",
    "rest",
    "rest_active",
    "rest_target",
    "_solver",
)


@contextlib.contextmanager
def restoring(obj, names):
    """Run a block; when it raises (anything), put the attributes ``names`` of ``obj`` back as they were."""
    saved = {name: getattr(obj, name, None) for name in names}
    try:
        yield
    except BaseException:
        for name, value in saved.items():
            setattr(obj, name, value)
        raise


def check_shape(shape):
    """The editor's shape: a 2D :class:`~defop.scene.shapes.Shape` (a name is loaded) with a moving handle.

    Returns
    -------
    shape : defop.scene.shapes.Shape
    """
    if isinstance(shape, str):
        shape = load_shape(shape)
    elif not isinstance(shape, Shape):
        raise ValueError(
            f"shape must be a Shape or the name of one (dop.shapes.names()), got {type(shape).__name__} {shape!r:.80}"
        )
    if shape.mesh.dim != 2:
        raise ValueError(
            f"shape must be a 2D shape for the editor (drags in the plane), got the {shape.mesh.dim}D "
            f"shape {shape.name!r}: write the 3D page instead, defop.editor.to_html(op, path, "
            f"shape=shape), and show it with IPython.display.IFrame(path)"
        )
    if shape.n_moving == 0:
        raise ValueError(f"shape {shape.name!r} has no moving handle to drag")
    return shape


def check_Q(Q, P):
    """Q (n,2) of the n moving handles (rest positions P), finite; a float copy."""
    Q = opt.real_array("Q", Q)
    if Q.shape != P.shape:
        raise ValueError(f"Q must have shape {P.shape} (the moving handles), got {Q.shape}")
    bad = ~np.isfinite(Q).all(axis=1)
    if bad.any():
        raise ValueError(f"handle {int(np.flatnonzero(bad)[0])} has a NaN or infinite position")
    return np.array(Q, dtype=float)


def check_index(i, n):
    """A moving handle's index in 0..n−1 (1.5 is refused, not truncated to 1)."""
    i = opt.integer("handle index", i)
    if not 0 <= i < n:
        raise ValueError(f"handle index {i} is out of range 0..{n - 1}")
    return i


def check_flag(name, value):
    """True or False (also numpy's bools, 0 and 1); ``bool("off")`` would be True."""
    if not isinstance(value, (bool, np.bool_)) and not (isinstance(value, numbers.Integral) and value in (0, 1)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def train_operator(shape, kind, energy, m=None, train_kw=None):
    """The DefOp of basis ``kind`` the editor trains on first use: :func:`defop.training.bootstrap.train` with at
    least the samples the basis needs (:func:`~defop.training.bootstrap.min_samples`; ``m`` default
    :func:`~defop.training.bootstrap.defaults` of its dimension), unless ``train_kw`` gives the samples.

    Returns
    -------
    defop.operator.DefOp
    """
    kw = {"energy": energy, "basis": kind, "progress": False, **(train_kw or {})}
    if "samples" not in kw:
        kw["m"] = max(defaults(shape.mesh.dim)[0] if m is None else int(m), min_samples(kind, shape.n_moving))
    return train(shape, **kw)[0]


def outside_regions(Q, regions):
    """Indices of the handles of Q (n,2) outside their sampling regions (lists of polygons; an empty list: none).

    Returns
    -------
    list of int
    """
    return [i for i, polys in enumerate(regions) if polys and not any(inside_polygon(Q[i], p) for p in polys)]


def extrapolating(Q, P, samples, reach=None):
    """Indices of the moving handles of Q where the operator extrapolates: beyond
    :data:`~defop.operator.core.EXTRAPOLATION_FACTOR` times their farthest training sample
    (:func:`defop.operator.core.beyond_reach`), the rule of the operators' ExtrapolationWarning and of the page
    (``extrapolating`` in ``static/defop_editor.js``).

    Parameters
    ----------
    Q, P : (n,d) numpy array
        The handles and their rest positions.
    samples : (m,n,d) numpy array or None
        The training configurations; without them no handle extrapolates (the operator does not warn either).
    reach : (n,) numpy array, optional
        The farthest training offset of each handle instead of ``samples`` (a MovableOp's ``reach``, with P its
        current placement).

    Returns
    -------
    list of int
    """
    reach = training_reach(P, samples) if reach is None else np.asarray(reach, float)
    if reach is None:
        return []
    dist = np.linalg.norm(np.asarray(Q, float) - np.asarray(P, float), axis=-1)
    return np.flatnonzero(beyond_reach(dist, reach)).tolist()


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
    return [
        [poly for poly, _style in region_outlines(c, r, P, i, n) if len(poly) >= 3]
        for i, (c, r) in enumerate(zip(P, regions, strict=True))
    ]


def reach_polygons(P, samples, n=96):
    """Discs through the farthest training sample of each moving handle (when no regions are known): the reach of
    :func:`defop.operator.defop.training_reach`.

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
    reach = training_reach(P, samples)  # the operator's one definition of the reach
    if reach is None:
        return [[] for _ in P]
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
