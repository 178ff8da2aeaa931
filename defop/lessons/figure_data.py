"""Computations behind individual figures that the general modules do not cover.

* :func:`column_path`, :func:`lowest_of` and :func:`column_jumps`: Fig. 10 (global against local optima
  along vertical drags of the bar's handle, and the hysteresis between them);
* :func:`arc_samples` and :func:`arc_point`: Fig. 7 (configurations along a bending cantilever's tip path);
* :func:`fit_diagnostics`: Figs. 2 and 8 (why a richer Ψ can lose to a poorer one: train against held-out
  error and the conditioning of the handle-basis matrix Ψ(Q_k));
* :func:`subspace_floor`: Fig. 2 (the best error any Ψ can reach with a reduced Φ);
* :func:`grid_error`: Figs. 3, 5 (a DefOp's error over the whole grid of a ground-truth trajectory, which
  ranks the handle bases at a given sample count) and :func:`grid_errors_over_draws` (that ranking over several
  sample draws and counts).
* :func:`subset_fits` and :func:`subset_errors`: Figs. 8 and 9 (one solved ground truth, fitted by each Ψ from
  its first m samples, and the per-sample held-out error of each fit); :func:`joint_subset_fits`: the same for
  the movable-handle operator (one joint training's truth, fitted from its first m samples);
* :func:`local_rotation`: Fig. 9 (how far a part of the shape turns, e.g. an arm that folds).

Fig. 7 in 3D samples a beam's end patch with :func:`defop.training.sampling.patch_motions` and
:func:`defop.training.sampling.twist_bend_samples`. No plotting here (:mod:`defop.view.plot`), no notebook state.
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from ..analysis.metrics import approximation_error
from ..analysis.trajectories import Trajectory, check_scan, discontinuities, moving_batch, moving_rest_positions
from ..training import solves

__all__ = [
    "column_path",
    "lowest_of",
    "column_jumps",
    "arc_samples",
    "arc_point",
    "fit_diagnostics",
    "subspace_floor",
    "grid_error",
    "grid_errors_over_draws",
    "subset_fits",
    "subset_errors",
    "joint_subset_fits",
    "local_rotation",
]


def column_path(ny, nx, start="bottom"):
    """A boustrophedon scan of a (ny, nx) grid by columns: a user dragging the handle up and down.

    Column 0 (the smallest x) is swept first, from the bottom (``start="bottom"``) or the top, then
    column 1 in the other direction, ... Every step moves to a 4-neighbour.

    Returns
    -------
    path : (ny*nx, 2) numpy int array
        Grid indices ``(i, j)`` in visiting order.
    """
    check_scan(ny, nx, start)
    path = []
    for j in range(nx):
        up = (j % 2 == 0) == (start == "bottom")
        path.extend((i, j) for i in (range(ny) if up else range(ny - 1, -1, -1)))
    return np.asarray(path, dtype=np.int64)


def lowest_of(shape, runs, energy="sarap", solver_kw=None):
    """The global ground truth as the lowest verified minimum over several trajectories' solutions.

    At every grid point, :meth:`defop.variational.solver.Solver.solve_best` restarts from each run's solution at that
    point (e.g. the rest-pose solve of ``ground_truth_trajectories(mode="global")`` and the warm-started
    drags of ``mode="local"``) and keeps the lowest verified minimum. The result is therefore at most
    the energy of every run at every Q (up to the solver's tolerance), which a single start cannot promise.

    Parameters
    ----------
    shape : Shape
    runs : sequence of Trajectory
        On one grid, for the handle ``moving = 0``.
    energy : str
    solver_kw : dict, optional

    Returns
    -------
    Trajectory
        ``kind="global"``, with ``energy`` and ``converged`` filled in.
    """
    runs = list(runs)
    if not runs:
        raise ValueError("lowest_of needs at least one trajectory")
    grid = runs[0].grid
    if any(r.X.shape != runs[0].X.shape for r in runs):
        raise ValueError("every trajectory must be on the same grid")
    Q = grid.positions
    ny, nx = grid.shape
    samples = np.repeat(np.asarray(shape.P_moving, float)[None], ny * nx, axis=0)
    samples[:, 0] = Q.reshape(ny * nx, -1)
    starts = [[run.X[i, j] for run in runs] for i in range(ny) for j in range(nx)]
    res = solves.solve(shape, samples, energy, starts=starts, rest=False, progress=False, solver_kw=solver_kw)
    X = res.X.reshape(runs[0].X.shape)
    E = res.energy.reshape(ny, nx)
    conv = res.converged.reshape(ny, nx)
    return Trajectory(grid=grid, X=X, rest=shape.mesh.V.copy(), kind="global", converged=conv, energy=E)


def column_jumps(grid, D, factor=8.0):
    """Where each column of a trajectory jumps along y.

    Parameters
    ----------
    grid : HandleGrid
    D : (ny, nx) or (ny, nx, c) numpy array
        A trajectory (e.g. ``traj.of(v)``).
    factor : float
        As in :func:`defop.analysis.trajectories.discontinuities`.

    Returns
    -------
    y : (nx,) numpy array
        Per column, the mean q_y − p_y of the midpoints of its jumping vertical edges (NaN if none).
    """
    _, ey = discontinuities(D, factor)
    mid = 0.5 * (grid.ys[1:] + grid.ys[:-1])
    return np.array([mid[ey[:, j]].mean() if ey[:, j].any() else np.nan for j in range(ey.shape[1])])


def arc_samples(pivot, tip, angle, m, rng, jitter=0.02):
    """m handle positions of a cantilever's tip bending up and down around ``pivot`` (the clamped end).

    A bar of length r = |tip − pivot| bent into a circular arc whose chord turns by the angle a has the
    chord length r·sin(a)/a; the samples sit on that curve (:func:`arc_point`), at stratified angles (one
    uniform draw in each of m equal bins of [−angle, angle]), with radial jitter uniform in ±``jitter``·r.

    Parameters
    ----------
    pivot, tip : (2,) array_like
        The clamped end and the rest position of the moving handle.
    angle : float
        Largest chord angle, radians.
    m : int
    rng : numpy.random.Generator
    jitter : float

    Returns
    -------
    Q : (m,1,2) numpy array
        One moving handle per configuration (``train(..., samples=Q)``).
    """
    if m < 1 or not 0 < angle < np.pi:
        raise ValueError(f"need m >= 1 and 0 < angle < pi, got m={m}, angle={angle}")
    edges = np.linspace(-angle, angle, m + 1)
    a = edges[:-1] + rng.uniform(size=m) * np.diff(edges)
    return arc_point(pivot, tip, a, 1 + rng.uniform(-jitter, jitter, size=m))


def arc_point(pivot, tip, a, scale=1.0):
    """(k,1,2) tip positions of a bar bent into circular arcs whose chords turn by the angles ``a`` (radians).

    The chord has length scale·r·sin(a)/a with r = |tip − pivot| (the bar keeps its length).
    """
    pivot, tip = np.asarray(pivot, float), np.asarray(tip, float)
    a = np.atleast_1d(np.asarray(a, float))
    r = np.linalg.norm(tip - pivot) * np.sinc(a / np.pi) * scale
    a0 = np.arctan2(*(tip - pivot)[::-1]) + a
    return (pivot + r[:, None] * np.column_stack([np.cos(a0), np.sin(a0)]))[:, None, :]


def fit_diagnostics(op, Q_train, X_train, Q_test, X_test):
    """Why a fit generalises or not: train and held-out error per sample and the conditioning of Ψ(Q_k).

    Parameters
    ----------
    op : DefOp
    Q_train, Q_test : (m,n,2) numpy arrays
    X_train, X_test : (m,n_vertices,2) numpy arrays

    Returns
    -------
    dict
        ``train``, ``test``: the mean (8a)/n per sample of each set, (8a)/n over its N samples divided by N
        (so the two sets compare; (8a)/n over N is :func:`defop.analysis.metrics.approximation_error`);
        ``cond``: 2-norm condition number of the (m, |Ψ|) matrix Ψ(Q_k) (the fit's handle-basis design matrix);
        ``size``: |Ψ|; ``m``: number of training samples.
    """
    Psi = np.asarray(op.psi(np.asarray(Q_train, float)))
    s = np.linalg.svd(Psi, compute_uv=False)
    return {
        "train": approximation_error(op, Q_train, X_train) / len(Q_train),
        "test": approximation_error(op, Q_test, X_test) / len(Q_test),
        "cond": float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
        "size": int(op.handle_basis.size),
        "m": int(len(Q_train)),
    }


def subspace_floor(mesh, X, spatial="reduced", k=100):
    """The (8a)/n over N = len(X) samples of the best deformations in span Φ (M-orthogonal projections onto Φ).

    No handle basis Ψ can do better than this floor, so it bounds what a richer Ψ can gain over a poorer one
    for a reduced Φ (Fig. 2).

    Parameters
    ----------
    mesh : Mesh
    X : (k,n_vertices,2) numpy array
        Ground-truth deformations.
    spatial : str or defop.operator.spatial.SpatialBasis
    k : int
        Size of the reduced Φ (as in :func:`defop.operator.fit.fit`).

    Returns
    -------
    float
        (1 / n_vertices) Σ_k ‖X_k − Π_Φ X_k‖²_M, the same normalisation as
        :func:`defop.analysis.metrics.approximation_error`.
    """
    from ..operator.spatial import make_spatial

    basis = make_spatial(mesh, spatial, k) if isinstance(spatial, str) else spatial
    X = np.asarray(X, float)
    R = X - np.stack([basis.evaluate(A) for A in basis.coefficients(X)])
    m = mesh.mass_matrix.diagonal()
    return float(np.einsum("v,kvc->", m, R**2) / mesh.n_vertices)


def grid_error(defop, truth, moving=0):
    """The Fig. 8 error of a DefOp over every handle position of a ground-truth trajectory's grid.

    Parameters
    ----------
    defop : DefOp
    truth : Trajectory
        Ground truth (:func:`defop.analysis.trajectories.ground_truth_trajectories`) on a grid of positions of
        the moving handle ``moving``; the other handles at rest.
    moving : int
        Index of the moving handle among the moving handles.

    Returns
    -------
    float
        The mean (8a)/n per sample over the grid: :func:`defop.analysis.metrics.approximation_error` over the
        N = ny·nx grid configurations, divided by N (so grids of different sizes compare).

    Raises
    ------
    ValueError
        A trajectory of another mesh, ``moving`` not an index of a moving handle, or a ground truth whose handle
        ``moving`` does not follow the grid (it was solved for another moving handle).
    """
    X = np.asarray(truth.X, float)
    if X.shape[2:] != (defop.n_vertices, 2):
        raise ValueError(f"the trajectory has {X.shape[2]} vertices, the DefOp {defop.n_vertices}")
    rest = moving_rest_positions(defop)
    moving = opt.integer("moving (the index of a moving handle)", moving, minimum=0, maximum=len(rest) - 1)
    Q = moving_batch(truth.grid, len(rest), moving, rest)
    handles, mask = getattr(defop, "handles", None), getattr(defop, "moving", None)
    if handles is not None and mask is not None:  # the truth's handle sits on the grid where its solve converged
        v = int(np.asarray(handles)[np.asarray(mask, bool)][moving])
        ok = np.ones(X.shape[:2], bool) if truth.converged is None else np.asarray(truth.converged, bool)
        off = float(np.abs(X[:, :, v] - truth.grid.positions)[ok].max(initial=0.0))
        if not off <= 1e-9 * defop.mesh.bbox_diagonal:
            raise ValueError(
                f"moving handle {moving} (vertex {v}) is {off:.3g} off the trajectory's grid: "
                "was the ground truth solved for another moving handle?"
            )
    return approximation_error(defop, Q, X.reshape(len(Q), -1, 2)) / len(Q)


def grid_errors_over_draws(shape, truth, regions, ms, seeds, bases, energy="sarap"):
    """:func:`grid_error` of each handle basis fitted to several independent sample draws of several sizes.

    One draw is a single outcome: whether a richer Ψ beats a poorer one at a small m can depend on where the
    few samples fell. This trains (:func:`defop.training.bootstrap.train`, cached) on ``sample_handles(..., m,
    rng=seed)``
    for every m and seed and measures every basis against the ground truth over the whole grid.

    Parameters
    ----------
    shape : Shape
    truth : Trajectory
        Ground truth on a grid of positions of the first moving handle.
    regions : list of defop.scene.regions.Region or dict
        One sampling region per moving handle (:func:`defop.training.sampling.sample_handles`).
    ms : sequence of int
        Sample counts.
    seeds : sequence of int
        One draw per seed.
    bases : sequence of str
        Handle bases Ψ.
    energy : str

    Returns
    -------
    errors : (len(ms), len(seeds), len(bases)) numpy array
        The mean (8a)/n per sample over the grid configurations.
    """
    from ..training.bootstrap import train
    from ..training.sampling import sample_handles

    errors = np.empty((len(ms), len(seeds), len(bases)))
    for a, m in enumerate(ms):
        for b, seed in enumerate(seeds):
            samples = sample_handles(shape.P_moving, regions, m, rng=seed)
            for c, basis in enumerate(bases):
                op = train(shape, energy, basis, samples=samples, progress=False)[0]
                errors[a, b, c] = grid_error(op, truth)
    return errors


def subset_fits(shape, samples, X, bases, counts, **kw):
    """Operators fitted to the first m of one set of solved samples, for each handle basis and each m (Figs. 8, 9).

    The ground truth is solved once (e.g. by :func:`defop.training.bootstrap.train` with the largest m) and every
    smaller
    m reuses its first m samples, so two fits differ only in m and Ψ, never in the sampled configurations'
    solutions. A basis that m samples do not determine (m below :func:`defop.training.bootstrap.min_samples`) gets None.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (M,n,2) numpy array
        The solved configurations Q_k, in the order they were drawn.
    X : (M,n_vertices,2) numpy array
        Their ground-truth deformations.
    bases : sequence of str
        Handle bases Ψ (``"linear"``, ``"quadratic"``, ``"cubic"``, ``"tps"``).
    counts : sequence of int
        Sample counts m, each at most M.
    **kw
        Passed to :func:`defop.operator.fit.fit_shape` (``spatial``, ``k``).

    Returns
    -------
    dict
        ``(basis, m) -> DefOp`` (or None where the basis needs more samples), in the order bases × counts.

    Raises
    ------
    ValueError
        A count that is not a positive integer at most M, or an unknown basis.
    """
    from ..operator.fit import fit_shape
    from ..training.bootstrap import min_samples

    samples, X = np.asarray(samples, float), np.asarray(X, float)
    check_counts(counts, len(samples))
    need = {b: min_samples(b, shape.n_moving, shape.mesh.dim) for b in bases}  # an unknown basis raises here
    return {
        (b, int(m)): fit_shape(shape, samples[:m], X[:m], b, **kw) if m >= need[b] else None
        for b in bases
        for m in counts
    }


def check_counts(counts, total, minimum=1):
    """Raise ValueError unless every sample count is an integer from ``minimum`` to ``total`` (the solved samples)."""
    bad = [m for m in counts if int(m) != m or not minimum <= m <= total]
    if bad:
        raise ValueError(f"sample counts must be integers from {minimum} to {total} (the solved samples), got {bad}")


def joint_subset_fits(shape, placement, record, counts, **kw):
    """Movable-handle operators fitted to the first m joint samples of one training, for each m, with the CPU
    seconds of each fit (:func:`subset_fits` for :func:`defop.training.movable.train_movable`).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    placement : defop.scene.placement.PlacementRegions
    record : defop.training.movable.MovableRecord
        The training's joint samples (``idx``, ``Q``) in the order they were drawn and their truth ``X``.
    counts : sequence of int
        Sample counts m, each from 2 to the training's.
    **kw
        Passed to :func:`defop.operator.movable.fit_movable` (e.g. ``centres``).

    Returns
    -------
    dict
        ``m -> (MovableOp, CPU seconds of its fit)``.

    Raises
    ------
    ValueError
        A count that is not an integer from 2 to the training's m.
    """
    import time

    from ..operator.movable import fit_movable

    check_counts(counts, len(record.Q), minimum=2)  # as train_movable's m
    out = {}
    for m in map(int, counts):
        t0 = time.process_time()
        op = fit_movable(
            shape.mesh, shape.handles, shape.moving, placement, record.idx[:m], record.Q[:m], record.X[:m], **kw
        )
        out[m] = (op, time.process_time() - t0)
    return out


def subset_errors(operators, Q, X):
    """Each held-out configuration's own (8a)/n (N = 1) for each operator (NaN rows for a missing operator).

    Parameters
    ----------
    operators : dict
        ``key -> DefOp or None`` (e.g. from :func:`subset_fits`).
    Q : (k,n,2) numpy array
    X : (k,n_vertices,2) numpy array
        Ground truth at Q.

    Returns
    -------
    dict
        ``key -> (k,) numpy array``; each sums to the (8a)/n over N = k of
        :func:`defop.analysis.metrics.approximation_error`.
    """
    Q, X = np.asarray(Q, float), np.asarray(X, float)
    return {
        key: np.full(len(Q), np.nan) if op is None else approximation_error(op, Q, X, per_sample=True)[1]
        for key, op in operators.items()
    }


def local_rotation(rest, X, center, radius):
    """Angle of the best rotation taking the rest-pose points within ``radius`` of ``center`` to X (2-D Procrustes).

    How far a part of the shape turns, e.g. the tip of an arm that folds over: the angle θ maximising
    Σ_v ⟨R_θ (v − v̄), x_v − x̄⟩ over those points (atan2 of the cross and dot sums).

    Parameters
    ----------
    rest : (n_vertices,2) numpy array
        Rest-pose vertices V.
    X : (n_vertices,2) or (k,n_vertices,2) numpy array
        Deformed positions.
    center : (2,) array_like
    radius : float

    Returns
    -------
    float or (k,) numpy array
        Counter-clockwise angle in degrees, in (−180, 180].

    Raises
    ------
    ValueError
        Fewer than 2 rest-pose points within ``radius`` of ``center``, X of the wrong shape or not finite there,
        or a center that is not a (2,) point.
    """
    rest = np.asarray(rest, float)
    X = np.asarray(X, float)
    if X.shape[-2:] != rest.shape:
        raise ValueError(f"X must have shape (..., {len(rest)}, 2) like the rest pose, got {X.shape}")
    center = np.asarray(center, float)
    if center.shape != (2,):
        raise ValueError(f"center must be a point (2,), got shape {center.shape}")
    near = np.flatnonzero(np.linalg.norm(rest - center, axis=1) <= radius)
    if len(near) < 2:
        raise ValueError(f"only {len(near)} rest-pose point(s) within {radius} of {tuple(center)}: need at least 2")
    if not np.isfinite(X[..., near, :]).all():
        raise ValueError("X has NaN or infinite entries among the points within radius of center")
    A = rest[near] - rest[near].mean(axis=0)
    B = X[..., near, :] - X[..., near, :].mean(axis=-2, keepdims=True)
    dot = np.einsum("vc,...vc->...", A, B)
    cross = np.einsum("v,...v->...", A[:, 0], B[..., 1]) - np.einsum("v,...v->...", A[:, 1], B[..., 0])
    angle = np.degrees(np.arctan2(cross, dot))
    return float(angle) if np.ndim(angle) == 0 else angle
