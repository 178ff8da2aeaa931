"""A multi-valued operator against the solver along back-and-forth handle paths (§5), in 2D and 3D.

The truth of a drag is the solver's warm-started continuation: each frame solved from the previous frame's
minimum (:func:`solver_path`), so it keeps its branch until the branch folds and then jumps, which gives the
hysteresis loop of Fig. 10. :func:`compare` measures, frame by frame, the error (max vertex distance over the bbox
diagonal) of ``follow`` (:class:`defop.operator.branched.FollowSession`) and of a single-valued DefOp against that
truth, where each jumps, and the energy excess of ``global`` over the lowest verified minimum (the lower of the
minima the continuation reaches at the frame: out and back, a there-and-back path visits each Q twice). Pure
computation; drawing is in :mod:`defop.view.branches`.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from .. import options as opt
from ..scene import shapes
from ..training import branches as br
from ..variational.solver import Solver

__all__ = [
    "CASES",
    "Case",
    "PathComparison",
    "compare",
    "jump_frames",
    "line_path",
    "run_case",
    "solver_path",
    "targets_met",
    "near_error",
    "build",
    "grid_for",
    "path_of",
    "PARAMS",
]


def line_path(P, moving, start, end, steps):
    """A there-and-back handle path: ``steps`` steps from ``start`` to ``end``, then ``steps`` back.

    Parameters
    ----------
    P : (n_moving, d) numpy array
        Rest positions of the moving handles (the others stay there).
    moving : int or sequence of int
        Which moving handles follow the path (translated together).
    start, end : (d,) numpy arrays
        Displacements q − p of the two ends.
    steps : int
        Steps one way (≥ 1); the path has 2 steps + 1 frames.

    Returns
    -------
    Qs : (2 steps + 1, n_moving, d) numpy array
    """
    steps = opt.integer("steps", steps, minimum=1)
    P = np.asarray(P, dtype=float)
    idx = br.moving_set(P, moving)
    start, end = np.asarray(start, float), np.asarray(end, float)
    if start.shape != (P.shape[1],) or end.shape != start.shape:
        raise ValueError(f"start and end must be ({P.shape[1]},) displacements, got {start.shape} and {end.shape}")
    a = np.concatenate([np.linspace(0, 1, steps + 1), np.linspace(1, 0, steps + 1)[1:]])
    Qs = np.repeat(P[None], len(a), axis=0)
    Qs[:, idx] += (start + a[:, None] * (end - start))[:, None]
    return Qs


def solver_path(shape, Qs, energy="sarap", X0=None):
    """The solver's warm-started continuation along Qs: frame 0 from the rest pose's multi-start, then each frame
    from the previous minimum (no other start: the drag of a variational editor; :func:`defop.training.branches.sweep`).

    Returns
    -------
    X : (k, n_vertices, d) numpy array
    energy : (k,) numpy array
    converged : (k,) numpy bool array
    """
    solver = Solver(shape.mesh, shape.handles, energy=energy)
    targets = [shape.targets(q) for q in Qs]
    if not targets:
        return np.zeros((0, *shape.mesh.V.shape)), np.zeros(0), np.zeros(0, bool)
    if X0 is None:  # frame 0: the multi-start from the rest pose
        x, e, ok = br.solve_quietly(solver, targets[0], None, "global")
        X, E, conv, _ = br.sweep(solver, targets[1:], x)
        return np.concatenate([x[None], X]), np.concatenate([[e], E]), np.concatenate([[ok], conv])
    X, E, conv, _ = br.sweep(solver, targets, X0)
    return X, E, conv


def jump_frames(X, diag, factor=8.0):
    """Frames s where X jumps between s − 1 and s: the max vertex step is above ``factor`` × the median step."""
    step = np.abs(np.diff(X, axis=0)).max(axis=(1, 2)) / diag
    med = np.median(step)
    return np.flatnonzero(step > factor * max(med, 1e-12)) + 1


@dataclasses.dataclass
class PathComparison:
    """Errors and jumps of ``follow`` and a single-valued fit against the solver's continuation on one path.

    Attributes
    ----------
    Qs : (k, n_moving, d) numpy array
    follow, single : (k,) numpy arrays
        Per-frame error: max vertex distance to the solver's frame over the bbox diagonal.
    jumps : dict of str -> (j,) int arrays
        Frames where the solver, ``follow`` (its branch switches) and the single-valued fit jump.
    near : (k,) numpy bool array
        Frames within ``window`` steps of a solver jump.
    excess : (k,) numpy array
        (E(global's X) − lowest verified minimum) / lowest, per frame.
    labels : (k,) numpy int array
        ``follow``'s branch per frame.
    X : dict of str -> (k, n_vertices, d) numpy arrays
        The frames of ``solver``, ``follow``, ``global`` and ``single``.
    """

    Qs: np.ndarray
    follow: np.ndarray
    single: np.ndarray
    jumps: dict
    near: np.ndarray
    excess: np.ndarray
    labels: np.ndarray
    X: dict = dataclasses.field(default_factory=dict)


def _error(X, ref, diag):
    return np.linalg.norm(X - ref, axis=-1).max(axis=-1) / diag


def compare(shape, bop, single, Qs, energy="sarap", window=5, truth=None):
    """``follow``, ``global`` and a single-valued DefOp against the solver's continuation along Qs.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    bop : defop.operator.branched.BranchedOperator
    single : defop.operator.DefOp
    Qs : (k, n_moving, d) numpy array
        The path (e.g. :func:`line_path`).
    energy : str
    window : int
        "Near the jump": within this many steps of a frame where the solver jumps.
    truth : tuple, optional
        (X, E, converged) of :func:`solver_path` along Qs, when already computed.

    Returns
    -------
    PathComparison
    """
    diag = shape.mesh.bbox_diagonal
    X, E, ok = solver_path(shape, Qs, energy) if truth is None else truth
    if not ok.all():
        warnings.warn(
            f"{int((~ok).sum())} of {len(ok)} continuation solves did not converge", stacklevel=opt.user_stacklevel()
        )
    # a there-and-back path visits each Q twice: out on one branch, back on the other where both exist
    E = np.where(ok, E, np.inf)
    lowest = np.minimum(E, E[::-1]) if np.allclose(Qs, Qs[::-1]) else E
    solver = Solver(shape.mesh, shape.handles, energy=energy)
    session = bop.session()
    labels, Xf = session.run(Qs)
    Xs = single(Qs)
    Xg = bop(Qs)
    Eg = solver_energies(solver, Xg)
    solver_jumps = jump_frames(X, diag)
    frames = np.arange(len(Qs))
    near = np.zeros(len(Qs), bool)
    for j in solver_jumps:
        near |= np.abs(frames - j) <= window
    jumps = {
        "solver": solver_jumps,
        "follow": np.flatnonzero(np.diff(labels) != 0) + 1,
        "single": jump_frames(Xs, diag),
    }
    out = {"solver": X, "follow": Xf, "global": Xg, "single": Xs}
    return PathComparison(
        Qs, _error(Xf, X, diag), _error(Xs, X, diag), jumps, near, (Eg - lowest) / lowest, labels, out
    )


def solver_energies(solver, X):
    """E(X) for a batch (k, n_vertices, d) (the true energy, Eq. 10 / 11)."""
    return np.array([solver.energy_of(x) for x in X])


def near_error(c, window=5):
    """``follow``'s and the single-valued fit's mean error over the frames within ``window`` steps of each solver
    jump, leaving out in each jump's window the one frame where ``follow``'s error is largest (a jump one step off
    puts one frame on the other branch). Returns (follow, single, frames used)."""
    frames = np.arange(len(c.Qs))
    keep = c.near.copy()
    for j in c.jumps["solver"]:
        win = np.flatnonzero(np.abs(frames - j) <= window)
        keep[win[np.argmax(c.follow[win])]] = False
    if not keep.any():
        return float("nan"), float("nan"), 0
    return float(c.follow[keep].mean()), float(c.single[keep].mean()), int(keep.sum())


def targets_met(c, catalogue=True, cost=None, window=5):
    """The targets of a multi-valued operator on one :class:`PathComparison`: a dict of name -> (value, passed).

    * ``follow`` jumps as often as the solver, each within 1 step of a solver jump;
    * near the solver's jumps (``window`` steps, :func:`near_error`), ``follow``'s mean error ≤ 1e-2 of the diagonal;
    * elsewhere, ``follow``'s mean error ≤ 1.1× the single-valued fit's (catalogue) or ≤ 1.5× (random cases);
    * with ``cost`` (multi- / single-valued training, CPU s): ≤ 3.
    """
    js, jf = c.jumps["solver"], c.jumps["follow"]
    dist = [int(np.min(np.abs(jf - j))) if len(jf) else 10**9 for j in js]
    f_near, _, _ = near_error(c, window)
    far = ~c.near
    f_far = float(c.follow[far].mean()) if far.any() else float("nan")
    s_far = float(c.single[far].mean()) if far.any() else float("nan")
    bound = 1.1 if catalogue else 1.5
    out = {
        "jumps: as many as the solver, each within 1 step": (dist, len(jf) == len(js) and all(d <= 1 for d in dist)),
        "near the jumps: follow mean error / diagonal <= 1e-2": (f_near, f_near <= 1e-2),
        "elsewhere: follow / single mean error <= 1.1 (catalogue), 1.5 (random)": (
            f_far / max(s_far, 1e-300),
            f_far <= bound * s_far,
        ),
    }
    if cost is not None:
        out["training cost multi / single <= 3"] = (cost, cost <= 3.0)
    return out


#: the catalogue's measured cases: the shape (and its vertex count), the moving handles and the there-and-back path
#: (two ends, displacements from rest in the plane of :data:`AXES`). Every other handle is fixed (the U's second tip
#: too: Ψ is then a function of the handles that move, as the samples need). ``plank_3d`` is the bar in 3D (its end
#: handle dragged in the plane z = const). Everything else is :data:`PARAMS`, the same for every case.
CASES = {
    "bar": {"shape": "bar", "moving": 0, "path": ((-0.15, -0.3), (-0.15, 0.3))},
    "u_shape": {"shape": "u_shape", "moving": 0, "path": ((-0.2, -0.25), (0.4, -0.25))},
    "plank_3d": {"shape": "plank_3d", "moving": 0, "path": ((-0.15, -0.3), (-0.15, 0.3))},
}
#: the axes of every case's grid plane and path
AXES = (0, 1)
#: one set of parameters for every case (catalogue and random): the grid's samples per side ``n``, its
#: half width ``radius`` (the shapes are about 1 long), its centre (the path's midpoint, a rule, not a number), one
#: continuation sweep along the path's main direction, bisection ``depth`` steps towards each fold, the edge minima
#: kept, the grouping ``tol``, TPS Ψ and hat Φ; ``FOLLOW_RATIO`` is :data:`defop.training.branches.FOLLOW_RATIO`
PARAMS = {"n": 17, "radius": 0.3, "sweeps": 1, "depth": 3, "edges": True, "tol": 1e-3, "basis": "tps"}


@dataclasses.dataclass
class Case:
    """One measured case (:func:`run_case`): the shape, the minima, the branches, both operators and the comparison."""

    name: str
    shape: object
    minima: object
    branches: object
    operator: object
    single: object
    comparison: PathComparison
    fit_seconds: float


def grid_for(shape, moving, path, n=None):
    """The grid of :data:`PARAMS` for a path: samples (n², n_moving, d) centred at the path's midpoint, and the
    sweeps (one boustrophedon scan along the path's main direction, so it crosses the folds the path crosses)."""
    n = opt.integer("n", PARAMS["n"] if n is None else n, minimum=2)
    ends = np.asarray(path, dtype=float)
    Q = br.grid_samples(shape, PARAMS["radius"], n, moving, ends.mean(axis=0), AXES)
    by = "columns" if abs(ends[1, 1] - ends[0, 1]) >= abs(ends[1, 0] - ends[0, 0]) else "rows"
    sweeps = [br.scan_order(n, n, by, reverse=bool(c % 2)) for c in range(PARAMS["sweeps"])]
    return Q, sweeps


def build(shape, moving, path, n=None, energy="sarap", cache=True):
    """Discover, certify and fit a shape's branches on the grid of :data:`PARAMS` around a path.

    Returns
    -------
    minima, branches, bop, single, fit_seconds
        The discovery's minima, the certified SampledBranches, the BranchedOperator, the single-valued DefOp (the lowest
        minimum per sample), the CPU seconds of the two fits.
    """
    Q, sweeps = grid_for(shape, moving, path, n)
    minima = br.discover(shape, Q, sweeps, energy, cache=cache)
    branches = br.group(shape, minima, PARAMS["tol"], energy, margins=False)
    branches = br.certify_branches(
        shape, branches, PARAMS["depth"], PARAMS["edges"], PARAMS["tol"], energy, cache=cache
    )
    t0 = time.process_time()
    bop = br.fit_branched(shape, branches, energy, PARAMS["basis"])
    single = br.fit_single(shape, minima, energy, PARAMS["basis"])
    return minima, branches, bop, single, time.process_time() - t0


def path_of(shape, moving, path, steps):
    """The there-and-back path Qs of a case's two ends (in the plane of :data:`AXES`)."""
    ends = np.zeros((2, shape.mesh.V.shape[1]))
    ends[:, list(AXES)] = path
    return line_path(shape.P_moving, moving, ends[0], ends[1], steps)


def run_case(name, n=None, steps=100, energy="sarap"):
    """Discover, certify and fit the branches of a case of :data:`CASES` (:func:`build`), compare along its path.

    Parameters
    ----------
    name : str
        A key of :data:`CASES`.
    n : int, optional
        Samples per side of the grid (default: :data:`PARAMS`' n).
    steps : int
        Steps of the path one way (there and back: 2 steps + 1 frames).

    Returns
    -------
    Case
    """
    if name not in CASES:
        raise ValueError(f"name must be one of {sorted(CASES)}, got {name!r}")
    c = CASES[name]
    shape = one_moving(shapes.load(c["shape"], c.get("vertices")), c["moving"])
    moving = np.arange(len(shape.P_moving))  # the case's handles, all of them moving together
    minima, branches, bop, single, fit_seconds = build(shape, moving, c["path"], n, energy)
    Qs = path_of(shape, moving, c["path"], steps)
    return Case(name, shape, minima, branches, bop, single, compare(shape, bop, single, Qs, energy), fit_seconds)


def one_moving(shape, moving):
    """The shape with only the moving handles ``moving`` (an index or indices among the moving handles) moving."""
    idx = np.flatnonzero(shape.moving)
    keep = np.sort(br.moving_set(idx, moving))  # the regions follow the handles' order
    if len(keep) == len(idx):
        return shape
    flags = np.zeros_like(shape.moving)
    flags[idx[keep]] = True
    return dataclasses.replace(shape, moving=flags, regions=[shape.regions[i] for i in keep])
