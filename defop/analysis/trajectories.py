"""Trajectories of points: displacement of a point as a function of a handle's displacement.

Paper §3.1 (Fig. 3, Fig. 5) and §5 (Fig. 10). Fix a point x of the shape and move ONE handle
q over a grid of positions while every other handle stays at rest. The *trajectory* of x is

    T_x(q) = D(x, Q(q)) - x,        q in a grid around the handle's rest position p,

for a deformation operator D: the variational DefOp D^E_Φ (the "ground truth", problem (6))
or a trained (Φ, Ψ)-DefOp (Eq. 3). Because Q has 2 free coordinates, each component of T_x
is a height field over the plane of handle positions, which is what Fig. 3 and Fig. 5 draw.

Facts the notebooks check with this module:

* A DefOp with the linear handle basis Ψ = {1, q^x, q^y} has an exactly affine trajectory
  (``plane_fit_residual`` ~ 1e-15).
* The variational DefOp of a non-convex energy is the minimiser of problem (6) and can jump
  when the minimiser switches branch; ``neighbour_jumps``/``jump_ratio``/``discontinuities``
  detect the jumps on the grid.
* A smooth interpolant of samples on both sides of such a jump rings: ``range_and_error`` measures how
  far each approximation leaves the ground truth's range (the TPS overshoot of Figs. 3, 5).
* "Global" ground truth: every grid point is solved independently by the solver's multi-start
  (``start="global"``: rest pose, saddles escaped, lowest verified minimum; no history). "Local"
  ground truth: the solves are warm-started along a path through the grid (a serpentine scan, like a user
  dragging the handle), so the result depends on the path (§5, Fig. 10). Both run on the sample engine
  (:func:`defop.training.solves.solve` and :func:`defop.training.paths.sweep`).

Everything here is pure computation; drawing lives in ``defop.view.plot`` / ``defop.view.render``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import options as opt
from ..training import batch, paths, solves
from ..training import cache as cache_mod
from ..variational.energies import check_energy
from ..variational.solver import NotConvergedWarning
from . import trajectory_metrics as tm
from .trajectory_metrics import *  # noqa: F403 (the measurements, re-exported: their home until they moved)

__all__ = [
    "moving_batch",
    "moving_rest_positions",
    "HandleGrid",
    "Trajectory",
    "defop_trajectories",
    "ground_truth_trajectories",
    "handle_grid",
    "serpentine_path",
    *tm.__all__,
]


# --------------------------------------------------------------------------- grids
@dataclass(frozen=True)
class HandleGrid:
    """A rectangular grid of positions of one moving handle.

    Attributes
    ----------
    center : (2,) numpy array
        Rest position p of the moving handle.
    xs : (nx,) numpy array
        Handle displacements along x (increasing), i.e. q^x - p^x.
    ys : (ny,) numpy array
        Handle displacements along y (increasing).

    Grid arrays are indexed ``[i, j]`` with row ``i`` <-> ``ys[i]`` and column ``j`` <-> ``xs[j]``,
    so ``imshow(Z, origin="lower", extent=grid.extent)`` draws them the right way up.
    """

    center: np.ndarray
    xs: np.ndarray
    ys: np.ndarray

    @property
    def shape(self):
        """(ny, nx)."""
        return (len(self.ys), len(self.xs))

    @property
    def size(self) -> int:
        return len(self.ys) * len(self.xs)

    @property
    def displacements(self):
        """(ny, nx, 2) numpy array: handle displacement q - p at every grid point."""
        gx, gy = np.meshgrid(self.xs, self.ys)
        return np.stack([gx, gy], axis=-1)

    @property
    def positions(self):
        """(ny, nx, 2) numpy array: handle position q at every grid point."""
        return self.center[None, None, :] + self.displacements

    @property
    def spacing(self):
        """(hx, hy): grid steps (the largest step if the grid is not uniform)."""
        hx = float(np.max(np.diff(self.xs))) if len(self.xs) > 1 else 0.0
        hy = float(np.max(np.diff(self.ys))) if len(self.ys) > 1 else 0.0
        return hx, hy

    @property
    def extent(self):
        """(xmin, xmax, ymin, ymax) of the displacements (for ``imshow``)."""
        return (float(self.xs[0]), float(self.xs[-1]), float(self.ys[0]), float(self.ys[-1]))

    def nearest(self, displacement):
        """Grid index ``(i, j)`` nearest to a handle displacement ``(dx, dy)``."""
        d = np.asarray(displacement, dtype=float)
        if d.shape != (2,):
            raise ValueError(f"displacement must have shape (2,), got {d.shape}")
        return int(np.argmin(np.abs(self.ys - d[1]))), int(np.argmin(np.abs(self.xs - d[0])))


def handle_grid(center, radius, n, ny=None, radius_y=None):
    """Square (or rectangular) grid of handle positions around a rest position.

    Parameters
    ----------
    center : (2,) numpy array
        Rest position p of the moving handle.
    radius : float
        Half width of the grid along x: displacements run over [-radius, radius].
    n : int
        Points along x (>= 2). Odd ``n`` puts the rest position on the grid.
    ny : int, optional
        Points along y (default ``n``).
    radius_y : float, optional
        Half height along y (default ``radius``).

    Returns
    -------
    HandleGrid
    """
    center = np.asarray(center, dtype=float).reshape(-1)
    if center.shape != (2,) or not np.isfinite(center).all():
        raise ValueError(f"center must be a finite (2,) point, got {center!r}")
    ny = n if ny is None else ny
    radius_y = radius if radius_y is None else radius_y
    n, ny = opt.integer("n", n, minimum=2), opt.integer("ny", ny, minimum=2)
    radius, radius_y = opt.positive("radius", radius), opt.positive("radius_y", radius_y)
    xs = np.linspace(-radius, radius, int(n))
    ys = np.linspace(-radius_y, radius_y, int(ny))
    return HandleGrid(center=center, xs=xs, ys=ys)


def check_scan(ny, nx, start):
    """Validate the grid shape and start of a boustrophedon scan (:func:`serpentine_path`, column scans)."""
    if ny < 1 or nx < 1:
        raise ValueError(f"grid shape must be positive, got ({ny}, {nx})")
    if start not in ("bottom", "top"):
        raise ValueError(f"start must be 'bottom' or 'top', got {start!r}")


def serpentine_path(ny, nx, start="bottom"):
    """A boustrophedon scan of a (ny, nx) grid: every step moves to a 4-neighbour.

    Rows are scanned left-to-right, then right-to-left, ... A user dragging the handle
    back and forth over the region would trace such a path.

    Parameters
    ----------
    ny, nx : int
        Grid shape.
    start : {"bottom", "top"}
        Start at row 0 (bottom, smallest y) or at the last row.

    Returns
    -------
    path : (ny*nx, 2) numpy int array
        Grid indices ``(i, j)`` in visiting order.
    """
    check_scan(ny, nx, start)
    rows = range(ny) if start == "bottom" else range(ny - 1, -1, -1)
    path = []
    for r, i in enumerate(rows):
        cols = range(nx) if r % 2 == 0 else range(nx - 1, -1, -1)
        path.extend((i, j) for j in cols)
    return np.asarray(path, dtype=np.int64)


# ----------------------------------------------------------------- trajectories
@dataclass
class Trajectory:
    """Deformations over a grid of positions of one moving handle.

    Attributes
    ----------
    grid : HandleGrid
    X : (ny, nx, n_vertices, 2) numpy array
        Deformed vertex positions at every grid point.
    rest : (n_vertices, 2) numpy array
        Rest vertex positions.
    kind : str
        "global", "local" (ground truth) or the DefOp's handle basis name.
    converged : (ny, nx) numpy bool array or None
        Solver convergence flags (ground truth only).
    energy : (ny, nx) numpy array or None
        Final energy of each solve (ground truth only).
    path : (k, 2) numpy int array or None
        Visiting order of the warm-started ("local") solves.
    """

    grid: HandleGrid
    X: np.ndarray
    rest: np.ndarray
    kind: str
    converged: np.ndarray | None = None
    energy: np.ndarray | None = None
    path: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def of(self, vertex):
        """Trajectory T_x of one vertex: (ny, nx, 2) displacement X[vertex] - rest[vertex]."""
        vertex = int(vertex)
        if not 0 <= vertex < len(self.rest):
            raise ValueError(f"vertex {vertex} out of range [0, {len(self.rest)})")
        return self.X[:, :, vertex, :] - self.rest[vertex]

    def deformation(self, displacement):
        """Deformed vertices (n_vertices, 2) at the grid point nearest to a handle displacement."""
        i, j = self.grid.nearest(displacement)
        return self.X[i, j]


def moving_batch(grid, n_moving, moving, P_moving):
    """(k, n_moving, 2) handle batch: handle ``moving`` on the grid, the others at rest."""
    if isinstance(moving, (bool, np.bool_)) or not isinstance(moving, (int, np.integer)) or not 0 <= moving < n_moving:
        raise ValueError(f"moving handle index {moving!r} out of range [0, {n_moving}) (an integer)")
    Q = np.repeat(np.asarray(P_moving, dtype=float)[None], grid.size, axis=0)
    Q[:, moving] = grid.positions.reshape(-1, 2)
    return Q


def defop_trajectories(defop, grid, moving=0, kind=None, batch=4096):
    """Trajectories of a trained (Φ, Ψ)-DefOp (Eq. 3) by batch evaluation.

    Parameters
    ----------
    defop : DefOp
        Trained operator; ``defop(Q)`` maps (k, n_moving, 2) handle batches to (k, n_vertices, 2).
    grid : HandleGrid
        Positions of the moving handle (its center should be the handle's rest position).
    moving : int
        Which moving handle follows the grid (index among the moving handles); the others stay at rest.
    kind : str, optional
        Label (default: the handle basis name from ``defop.meta`` or the class name).
    batch : int
        Grid points evaluated per call.

    Returns
    -------
    Trajectory
    """
    _check_grid(grid)
    batch = opt.integer("batch", batch, minimum=1)
    P_moving = moving_rest_positions(defop)
    Q = moving_batch(grid, len(P_moving), moving, P_moving)
    parts = [np.asarray(defop(Q[s : s + batch])) for s in range(0, len(Q), batch)]
    X = np.concatenate(parts, axis=0)
    rest = np.asarray(defop.mesh.V, dtype=float)
    if kind is None:
        meta = getattr(defop, "meta", None) or {}
        kind = meta.get("basis") or type(getattr(defop, "handle_basis", defop)).__name__
    return Trajectory(grid=grid, X=X.reshape(grid.shape + X.shape[1:]), rest=rest, kind=str(kind))


def _check_grid(grid):
    if not isinstance(grid, HandleGrid):
        raise ValueError(f"grid must be a HandleGrid (see handle_grid), got {type(grid).__name__}")


def moving_rest_positions(defop):
    """The rest positions (n_moving, 2) of a DefOp's (or a peer's) moving handles."""
    P = np.asarray(defop.P, dtype=float)
    moving = getattr(defop, "moving", None)
    if moving is not None and len(np.atleast_1d(moving)) == len(P) and np.asarray(moving).dtype == bool:
        P = P[np.asarray(moving)]
    return P


# ------------------------------------------------------------ ground truth
def _cache_key(shape, grid, energy, mode, moving, path, solver_kw, solve_kw):
    """Key of a ground-truth trajectory: mesh, handles, grid, path and every solver setting."""
    arrays = (shape.mesh.V, shape.mesh.F, np.asarray(shape.handles), np.asarray(shape.moving))
    path = np.zeros((0, 2), np.int64) if path is None else np.asarray(path, np.int64)
    settings = solves.settings_of(shape, energy, solver_kw)
    return cache_mod.key("traj", *arrays, grid.center, grid.xs, grid.ys, path, energy, mode, moving, settings, solve_kw)


def _trajectory_expect(grid, n_vertices):
    ny, nx = grid.shape
    return {"X": ((ny, nx, n_vertices, 2), "f"), "energy": ((ny, nx), "f"), "converged": ((ny, nx), "b")}


def _check_ground_truth(shape, grid, energy, mode, moving, path, n_jobs):
    """:func:`ground_truth_trajectories`' arguments, checked before any work: (moving, path or None, the moving
    handles' rest positions)."""
    if mode not in ("global", "local"):
        raise ValueError(f"mode must be 'global' or 'local', got {mode!r}")
    _check_grid(grid)
    check_energy(energy)
    moving = opt.integer("moving", moving, minimum=0)
    opt.n_jobs(n_jobs)
    if mode == "local":
        path = serpentine_path(*grid.shape) if path is None else np.asarray(path, dtype=np.int64)
        tm.check_path(path, grid.shape)
    else:
        path = None
    P_moving = np.asarray(shape.P_moving, dtype=float)
    if not 0 <= moving < len(P_moving):
        raise ValueError(f"moving handle index {moving} out of range [0, {len(P_moving)})")
    if not np.allclose(grid.center, P_moving[moving]):
        raise ValueError(
            f"grid.center {grid.center} is not the rest position {P_moving[moving]} of moving handle {moving}"
        )
    return moving, path, P_moving


def ground_truth_trajectories(
    shape,
    grid,
    energy="sarap",
    mode="global",
    moving=0,
    path=None,
    n_jobs=None,
    cache=True,
    progress=False,
    solver_kw=None,
    solve_kw=None,
):
    """Trajectories of the variational DefOp D^E_Φ (problem (6)) over a grid of handle positions.

    Parameters
    ----------
    shape : Shape
        Mesh and handles; the handle ``moving`` (index among the moving handles) follows the grid,
        every other handle stays at its rest position.
    grid : HandleGrid
        Handle positions (``grid.center`` should be the moving handle's rest position).
    energy : str
        "sarap" (Eq. 11), "arap" (Eq. 10) or "isometric".
    mode : {"global", "local"}
        "global": every grid point solved independently, ``Solver.solve(..., start="global")`` (the
        rest pose through flip-free continuation, saddles escaped along negative curvature, the lowest
        verified minimum; parallel over ``n_jobs``). "local": solved in the order ``path``
        (default: ``serpentine_path``), each warm-started from the previous solution.
    path : (k, 2) numpy int array, optional
        Visiting order for "local"; must visit every grid point once and move between 4-neighbours.
    n_jobs : int, optional
        joblib workers for "global" (default ``config.n_jobs()``).
    cache : bool
        Store/reuse the result under ``config.cache_dir()`` keyed by every parameter.
    progress : bool
        Show a tqdm progress bar.
    solver_kw, solve_kw : dict, optional
        Passed to ``Solver(...)`` and ``Solver.solve(...)``.

    Returns
    -------
    Trajectory
        With ``converged`` and ``energy`` filled in; a warning is issued if some solves did not converge.
    """
    moving, path, P_moving = _check_ground_truth(shape, grid, energy, mode, moving, path, n_jobs)
    store = cache_mod.open_cache(cache)  # a bad DEFOP_CACHE fails here, before any work
    solver_kw, solve_kw = dict(solver_kw or {}), dict(solve_kw or {})
    ny, nx = grid.shape
    key = None if store is None else _cache_key(shape, grid, energy, mode, moving, path, solver_kw, solve_kw)
    Qm = moving_batch(grid, len(P_moving), moving, P_moving)

    def compute():
        if mode == "global":  # the multi-start from the rest pose: Solver.solve(start="global")'s settings
            kw = {k: v for k, v in solve_kw.items() if k in ("tol", "max_iter")}
            res = solves.solve(
                shape,
                Qm,
                energy,
                n_jobs=n_jobs,
                progress=progress,
                desc="global solves",
                solver_kw=solver_kw,
                solve_kw=kw,
            )
            X, E, conv = res.X, res.energy, res.converged
        else:
            order = path[:, 0] * nx + path[:, 1]
            res = paths.sweep(shape, Qm[order], energy, None, progress, "warm-started solves", solver_kw, solve_kw)
            X, E, conv = (np.empty_like(a) for a in (res.X, res.energy, res.converged))
            X[order], E[order], conv[order] = res.X, res.energy, res.converged
        if not conv.all():
            warnings.warn(
                f"{int((~conv).sum())} of {len(conv)} {mode} ground-truth solves did not converge",
                NotConvergedWarning,
                stacklevel=opt.user_stacklevel(),
            )
        conv = conv.reshape(ny, nx).astype(bool)
        return {"X": X.reshape(ny, nx, -1, 2), "energy": E.reshape(ny, nx), "converged": conv}

    z = batch.load_or_compute(store, "traj", key, _trajectory_expect(grid, shape.mesh.n_vertices), compute)
    return Trajectory(
        grid=grid,
        X=z["X"],
        rest=shape.mesh.V.copy(),
        kind=mode,
        converged=z["converged"],
        energy=z["energy"],
        path=path,
    )
