"""Branch discovery: every verified minimum of problem (6) at the samples Q_k, grouped into branches (§5).

D^E is multi-valued where problem (6) has several local minima (the bar of Fig. 10 buckles up or down). The
single-valued training keeps one minimum per Q_k; here every verified minimum we can reach is kept:

1. **starts** (:func:`discover`): at each Q_k the multi-start of the single-valued training
   (:meth:`defop.variational.solver.Solver.solve_best` from the rest pose, saddles escaped: source 0), plus the
   minima that **continuation** reaches: each sweep visits the samples in an order where consecutive samples are
   neighbours and warm-starts every solve from the previous minimum (a user's drag; sources 1..).
2. **grouping** (:func:`group`): minima closer than ``tol`` (M-norm RMS distance over the bounding-box diagonal)
   at one Q_k are one. Where a Q_k holds two distinct minima, their difference is the mode that separates the
   branches: u is the leading M-weighted principal direction of these differences (for the bar: the buckling
   mode), and every minimum gets the score s(X) = ⟨X − x, u⟩_M. The threshold t(Q) = t_0 + t_1 · (Q − P) is the
   least-squares plane through the midpoints of the coexisting pairs' scores; branch = side of t(Q).
   Justification: two minima at one Q are on different sides (checked: ``conflicts`` counts Q_k where two distinct
   minima fell on one side; the lower is kept), and along a branch score − t is continuous, so it changes side
   only where the two sheets meet without a fold (one minimum), never across a fold. A constant t does not do:
   on the bar the minimum the drag continues from the bottom of a compressed column (the mid-bar point up) has a
   score that grows as the handle moves down, past the other sheet's scores higher up the column (measured:
   +0.021 at q − p = (−0.15, −0.3), where the wedge's midpoints are about +0.05). With no Q_k holding two minima there
   is one branch. Label 0 is the branch holding the rest pose (the side of s(x) = 0), so labels are stable.
   Each kept minimum gets its **stability margin** (:func:`stability_margin`): the reduced Hessian's eigenvalue
   of the eigenvector most parallel to u, which vanishes at the branch's fold.
3. **domains** (:mod:`defop.training.branch_domains`): every sample bordering branch b's domain is certified
   present or absent by a solve warm-started from b, the edge between them is bisected towards the fold, and
   :mod:`defop.operator.domains` fits b's domain function g_b from both sides (the signed distance to the edge).
   Without certification (format 1) the domain is estimated from λ²_b(Q), fitted on b's own samples (zero at a
   fold: a saddle-node's smallest eigenvalue vanishes like the square root of the distance), and the side score.

:func:`fit_branched` fits one DefOp per branch (:func:`defop.operator.fit.fit`, same bases and constraints:
Prop. 2 everywhere, (8b) on every branch since the fit always includes the rest pose) and E_b, λ²_b with the same
Ψ (:func:`defop.operator.fit.fit_values`). :func:`fit_single` is the single-valued fit to the lowest minimum per
sample, for comparison.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import options as opt
from ..operator.branched import Branch as OperatorBranch
from ..operator.branched import BranchedOperator
from ..operator.domains import box_of, domain_values, fit_domain
from ..operator.fit import fit_shape, fit_values
from ..variational.energies import check_energy
from ..variational.solver import NotConvergedWarning, Solver
from ..variational.verify import KINK
from . import batch
from . import cache as cache_mod

__all__ = [
    "Branch",
    "Branches",
    "Minima",
    "scan_order",
    "discover",
    "fit_branched",
    "fit_single",
    "grid_samples",
    "moving_set",
    "refine_folds",
    "group",
    "stability_margin",
]


# --------------------------------------------------------------------------- samples and sweeps
def moving_set(P, moving):
    """The moving handles ``moving`` names (an index or a sequence of indices into P's rows), as an int array."""
    idx = np.atleast_1d(np.asarray(moving))
    if idx.ndim != 1 or len(idx) == 0 or idx.dtype.kind not in "iu" or not ((idx >= 0) & (idx < len(P))).all():
        raise ValueError(f"moving must index the {len(P)} moving handles (an int or a sequence of ints): {moving!r}")
    if len(np.unique(idx)) != len(idx):
        raise ValueError(f"moving must not repeat a handle, got {moving!r}")
    return idx


def grid_samples(shape, radius, n, moving=0, offset=(0.0, 0.0), axes=(0, 1)):
    """Q_k on an n × n grid of displacements of the moving handles ``moving`` (the others at rest), rows of y, then x.

    Every handle in ``moving`` is translated by the same displacement, in the plane of the coordinate ``axes``: in
    2D one handle in the plane; in 3D a patch of handles moved together (``plank_3d``'s end, Fig. 10 in 3D).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    radius : float
        Half width of the grid (displacements in [−radius, radius]²).
    n : int
        Points per side (≥ 2; odd puts the rest pose on the grid).
    moving : int or sequence of int
        Which moving handles.
    offset : (2,) sequence of float
        Displacement of the grid's centre from the rest position, along ``axes`` (default: centred at rest).
    axes : (2,) sequence of int
        The two coordinate axes of the grid's plane.

    Returns
    -------
    Q : (n², n_moving, d) numpy array
        Sample k = i n + j has the handles at p + offset + (xs[j], ys[i]) (along ``axes``).
    """
    n = opt.integer("n", n, minimum=2)
    radius = opt.positive("radius", radius)
    P = np.asarray(shape.P_moving, dtype=float)
    idx = moving_set(P, moving)
    axes = np.asarray(axes)
    if (
        axes.shape != (2,)
        or axes.dtype.kind not in "iu"
        or not ((axes >= 0) & (axes < P.shape[1])).all()
        or (axes[0] == axes[1])
    ):
        raise ValueError(f"axes must be two different coordinate axes below {P.shape[1]}, got {axes.tolist()!r}")
    offset = np.asarray(offset, dtype=float)
    if offset.shape != (2,) or not np.isfinite(offset).all():
        raise ValueError(f"offset must be a finite (2,) displacement, got {offset!r}")
    t = np.linspace(-radius, radius, n)
    gx, gy = np.meshgrid(t, t)
    D = np.zeros((n * n, P.shape[1]))
    D[:, axes] = offset + np.stack([gx.ravel(), gy.ravel()], axis=-1)
    Q = np.repeat(P[None], n * n, axis=0)
    Q[:, idx] += D[:, None]
    return Q


def scan_order(ny, nx, by="columns", reverse=False):
    """Flat sample indices (i nx + j) of a boustrophedon scan of a (ny, nx) grid by columns or by rows.

    By columns: column 0 is swept from the bottom (from the top with ``reverse``), column 1 the other way, ...
    By rows: row 0 from the left (the right with ``reverse``), row 1 the other way, ... Every step joins
    4-neighbours, as a user dragging the handle back and forth across the region. A sweep should cross the folds
    (:func:`discover`): by columns when they run across the columns (the bar), by rows otherwise (the U's arm).

    Returns
    -------
    order : (ny nx,) numpy int array
    """
    ny, nx = opt.integer("ny", ny, minimum=1), opt.integer("nx", nx, minimum=1)
    if by not in ("columns", "rows"):
        raise ValueError(f"by must be 'columns' or 'rows', got {by!r}")
    outer, inner = (nx, ny) if by == "columns" else (ny, nx)
    order = []
    for a in range(outer):
        forward = (a % 2 == 0) != bool(reverse)
        for b in range(inner) if forward else range(inner - 1, -1, -1):
            order.append(b * nx + a if by == "columns" else a * nx + b)
    return np.asarray(order, dtype=np.int64)


# --------------------------------------------------------------------------- minima
@dataclasses.dataclass
class Minima:
    """Every end point of the starts at the samples (:func:`discover`).

    Attributes
    ----------
    samples : (m, n_moving, d) numpy array
    X : (m, s, n_vertices, d) numpy array
        The end point of source s at sample k (source 0: the multi-start from the rest pose; 1..: the sweeps).
    energy : (m, s) numpy array
        E(X) (NaN where not converged).
    converged : (m, s) numpy bool array
        A verified local minimum.
    seconds : dict
        CPU seconds of this process (``time.process_time``: the ratio of two costs does not depend on what else runs
        on the machine) of the rest-pose multi-start (``single``: the single-valued training's solves) and the
        sweeps, as measured when computed; ``cached`` says whether they were read from the cache.
    """

    samples: np.ndarray
    X: np.ndarray
    energy: np.ndarray
    converged: np.ndarray
    seconds: dict = dataclasses.field(default_factory=dict)


def stability_margin(solver, X, mode=None, k=4):
    """The stability margin at a minimum X: an eigenvalue of the exact reduced Hessian of problem (6) (S-ARAP's kink
    as check 5).

    Without ``mode``: λ_min, the smallest eigenvalue. With ``mode`` u: of the ``k`` smallest eigenpairs, the
    eigenvalue whose eigenvector is most parallel to u on the free dofs, i.e. the curvature of the mode that
    vanishes at the branch's fold (a saddle-node's critical eigenvector is the direction of the jump). λ_min alone
    can be another, unrelated soft mode that stays put (the U's arm: 0.0039 at every sample).
    :func:`smallest_eigenpairs` (one sparse LU).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    X : (n_vertices, d) numpy array
        A verified local minimum.
    mode : (n_vertices, d) numpy array, optional
    k : int
        Eigenpairs searched for the mode.

    Returns
    -------
    float
    """
    _, _, data, _ = solver.grad_hess(X, 0.0, project=False, kink=KINK)
    K = solver.hessian.full(data)
    u = None if mode is None else np.asarray(mode, dtype=float).ravel()[solver.free]
    lam, vec = smallest_eigenpairs(K, 1 if mode is None else k, u)
    return float(lam[0] if mode is None else lam[np.argmax(np.abs(vec.T @ u))])


def smallest_eigenpairs(K, k, start=None, block=6, iterations=10):
    """The k smallest eigenpairs of a symmetric positive definite sparse K: block inverse iteration, Rayleigh-Ritz.

    One sparse LU of K (shifted by 1e-8 of its mean diagonal below zero), then ``iterations`` block solves of
    ``max(block, k + 2)`` vectors (seeded; ``start`` among them). Eigenvalue i converges like (λ_i/λ_block+1)^its;
    measured on the bar: the four smallest to 1e-6 relative in 0.04 s, where ARPACK's shift-invert took 0.24 s.

    Returns
    -------
    lam : (k,) numpy array, ascending
    vec : (n, k) numpy array
    """
    from threadpoolctl import threadpool_limits

    n = K.shape[0]
    p = min(max(block, k + 2), n)
    shift = -1e-8 * float(np.abs(K.diagonal()).mean())
    # one BLAS thread: the blocks are (n, 6), too thin for threads; with two, OpenBLAS's waiting threads made a
    # 3D margin (plank_3d, 945 vertices, the machine busy) cost 0.74 CPU s instead of 0.077
    with threadpool_limits(limits=1):
        lu = spla.splu((K - shift * sp.identity(n, format="csc")).tocsc(), permc_spec="MMD_AT_PLUS_A")
        Y = np.random.default_rng(0).normal(size=(n, p))
        if start is not None:
            Y[:, 0] = start
        Y = np.linalg.qr(Y)[0]
        for _ in range(iterations):
            Y = np.linalg.qr(lu.solve(Y))[0]
        lam, V = np.linalg.eigh(Y.T @ (K @ Y))
    return lam[:k], Y @ V[:, :k]


def _solve(solver, targets, X0, start):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        r = solver.solve(targets, X0=X0, start=start)
    return np.asarray(r.X), float(r.energy), bool(r.converged)


#: :func:`edge_of_branch`: a bisection step whose minimum moves a vertex more than this many times the handles' step
#: left the branch (it jumped)
FOLLOW_RATIO = 4.0


def _compute(shape, solver, samples, sweeps, progress):
    m, s = len(samples), 1 + len(sweeps)
    X = np.empty((m, s, shape.mesh.n_vertices, shape.mesh.V.shape[1]))
    E, conv = np.full((m, s), np.nan), np.zeros((m, s), bool)
    targets = [shape.targets(q) for q in samples]
    t0 = time.process_time()
    bar = batch.progress(m * s, "branch discovery solves", progress)
    for k in range(m):  # source 0: the single-valued training's multi-start from the rest pose
        X[k, 0], E[k, 0], conv[k, 0] = _solve(solver, targets[k], None, "global")
        bar and bar.update(1)
    t1 = time.process_time()
    for c, order in enumerate(sweeps, start=1):  # continuation: each solve warm-started from the previous
        X[order[0], c], E[order[0], c], conv[order[0], c] = X[order[0], 0], E[order[0], 0], conv[order[0], 0]
        for prev, k in zip(order[:-1], order[1:]):
            X[k, c], E[k, c], conv[k, c] = _solve(solver, targets[k], X[prev, c], "local")
            bar and bar.update(1)
    t2 = time.process_time()
    bar and bar.close()
    E[~conv | ~np.isfinite(E)] = 0.0  # the cache stores finite numbers only; discover masks them out again
    return {"X": X, "energy": E, "converged": conv, "seconds": np.array([t1 - t0, t2 - t1])}


def discover(shape, samples, sweeps=(), energy="sarap", cache=True, progress=False, solver_kw=None):
    """Every verified minimum the starts reach at each sample Q_k: the multi-start, then continuation sweeps.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (m, n_moving, d) numpy array
    sweeps : sequence of (m,) int arrays
        Orders of the samples (each a permutation of 0..m−1, consecutive samples neighbours, e.g.
        :func:`scan_order`); each is one continuation.
    energy : str
    cache : bool
        Store/reuse the result under ``config.cache_dir()`` (keyed by the mesh, handles, samples, sweeps and
        every solver setting).
    progress : bool
    solver_kw : dict, optional
        Passed to ``Solver``.

    Returns
    -------
    Minima
    """
    check_energy(energy)
    samples = np.asarray(samples, dtype=float)
    P = np.asarray(shape.P_moving, dtype=float)
    if samples.ndim != 3 or samples.shape[1:] != P.shape or len(samples) < 1 or not np.isfinite(samples).all():
        raise ValueError(f"samples must be a finite (m, {P.shape[0]}, {P.shape[1]}) array, got {samples.shape}")
    sweeps = [np.asarray(o, dtype=np.int64) for o in sweeps]
    for c, o in enumerate(sweeps):
        if o.shape != (len(samples),) or not np.array_equal(np.sort(o), np.arange(len(samples))):
            raise ValueError(f"sweep {c} must be a permutation of the {len(samples)} sample indices, got {o.shape}")
    store = cache_mod.open_cache(cache)
    solver = Solver(shape.mesh, shape.handles, energy=energy, **dict(solver_kw or {}))
    key = None
    if store is not None:
        arrays = (shape.mesh.V, shape.mesh.F, np.asarray(shape.handles), np.asarray(shape.moving), samples)
        key = cache_mod.key("branch-minima-cpu", *arrays, *sweeps, energy, cache_mod.solver_settings(solver))
    m, s, n = len(samples), 1 + len(sweeps), shape.mesh.n_vertices
    d = shape.mesh.V.shape[1]
    expect = {"X": ((m, s, n, d), "f"), "energy": ((m, s), "f"), "converged": ((m, s), "b"), "seconds": ((2,), "f")}
    fresh = []

    def compute():
        fresh.append(True)
        return _compute(shape, solver, samples, sweeps, progress)

    z = batch.load_or_compute(store, "branch-minima", key, expect, compute)
    sec = z["seconds"]  # measured when computed (a cache hit returns the stored cost)
    return Minima(
        samples,
        z["X"],
        np.where(z["converged"], z["energy"], np.nan),
        z["converged"],
        {"single": float(sec[0]), "sweeps": float(sec[1]), "cached": not fresh},
    )


# --------------------------------------------------------------------------- grouping
@dataclasses.dataclass
class Branch:
    """The minima of one branch at the samples where it exists.

    Attributes
    ----------
    label : int
    samples : (k,) numpy int array
        Indices of the samples Q_k where the branch has a minimum (its domain on the samples).
    X : (k, n_vertices, d) numpy array
    energy, margin : (k,) numpy arrays
        E and the stability margin (:func:`stability_margin` along u) of each minimum (NaN where not computed).
    side : int
        +1 when the branch's scores are above the threshold t, −1 below.
    folds : (f, n_moving, d) numpy array or None
        After :func:`certify_branches`: the fold points (bisected edge of the domain); None before.
    segments : (s, 2, n_moving, d) numpy array or None
        The edge of the domain between the fold points (marching squares, refined across each cell).
    absent, uncertified : (·,) numpy int arrays
        After :func:`certify_branches`: grid samples certified absent, and bordering samples left uncertified.
    """

    label: int
    samples: np.ndarray
    X: np.ndarray
    energy: np.ndarray
    margin: np.ndarray
    side: int
    folds: np.ndarray = None
    segments: np.ndarray = None
    absent: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    uncertified: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))

    def report(self, Q):
        """count, domain extent (min and max of each coordinate of Q over the branch's samples), energy range."""
        q = np.asarray(Q)[self.samples].reshape(len(self.samples), -1)
        return {
            "label": self.label,
            "count": int(len(self.samples)),
            "q_min": q.min(axis=0),
            "q_max": q.max(axis=0),
            "energy": (float(self.energy.min()), float(self.energy.max())),
        }


@dataclasses.dataclass
class Branches:
    """The branches of D^E at the samples (:func:`group`).

    Attributes
    ----------
    samples : (m, n_moving, d) numpy array
    branches : list of Branch
        Label 0 holds the rest pose.
    mode : (n_vertices, d) numpy array
        u (M-unit), zeros with one branch.
    threshold : (1 + d n_moving,) numpy array
        t(Q) = t[0] + t[1:] · (Q − P).
    distinct : (m,) numpy int array
        Distinct verified minima found at each sample.
    conflicts : int
        Samples where two distinct minima fell on one side of t (the lower was kept).
    lowest : (m,) numpy int array
        The label of the lowest minimum at each sample (the single-valued training's choice).
    margin_seconds : float
        CPU seconds of the stability margins (``time.process_time``).
    certify_seconds : float
        CPU seconds of :func:`certify_branches` (certification and bisection solves).
    grid : int or None
        The number of grid samples (the first ``grid`` of ``samples``; edge minima follow); None: all.
    third : (·,) numpy int array
        Samples where more than two distinct minima were seen (discovery or certification): reported, not
        resolved (two branches, the lower minimum kept on each side).
    found : int
        Samples certification found on a branch that discovery had missed.
    """

    samples: np.ndarray
    branches: list
    mode: np.ndarray
    threshold: np.ndarray
    distinct: np.ndarray
    conflicts: int
    lowest: np.ndarray
    margin_seconds: float = 0.0
    certify_seconds: float = 0.0
    grid: int = None
    third: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    found: int = 0

    def reports(self):
        """Per branch: :meth:`Branch.report`."""
        return [b.report(self.samples) for b in self.branches]


def _rms(mesh, D):
    """M-weighted RMS length of displacement fields D (..., n_vertices, d)."""
    w = mesh.mass_matrix.diagonal()
    return np.sqrt(np.einsum("v,...vc->...", w, D**2) / w.sum())


def distinct_minima(mesh, minima, k, tol):
    """Sources (list of int) of the distinct verified minima at sample k, lowest energy first."""
    ok = np.flatnonzero(minima.converged[k])
    kept = []
    for c in ok[np.argsort(minima.energy[k, ok], kind="stable")]:
        if all(_rms(mesh, minima.X[k, c] - minima.X[k, j]) > tol * mesh.bbox_diagonal for j in kept):
            kept.append(int(c))
    return kept


def separating_mode(mesh, minima, pairs):
    """u (n_vertices, d), M-unit: the leading M-weighted principal direction of the differences of coexisting minima."""
    w = np.sqrt(mesh.mass_matrix.diagonal())[:, None]
    D = np.stack([((minima.X[k, a] - minima.X[k, b]) * w).ravel() for k, a, b in pairs])
    u = np.linalg.svd(D, full_matrices=False)[2][0].reshape(-1, mesh.V.shape[1]) / w
    return u / np.sqrt(np.einsum("v,vc->", mesh.mass_matrix.diagonal(), u**2))


def group(shape, minima, tol=1e-3, energy="sarap", margins=True):
    """Group the verified minima into branches by the side of the separating mode's score (module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    minima : Minima
    tol : float
        Minima at one sample closer than ``tol`` × bbox diagonal (M-weighted RMS) are one.
    energy : str
        The energy of the minima (for their stability margins, :func:`stability_margin` along u).
    margins : bool
        Compute the stability margins (λ²_b, the domain of format 1); False leaves them NaN (the domain is then
        fitted from :func:`certify_branches`' labels).

    Returns
    -------
    Branches
    """
    tol = opt.positive("tol", tol)
    mesh, m = shape.mesh, len(minima.samples)
    kept = [distinct_minima(mesh, minima, k, tol) for k in range(m)]
    if not any(kept):
        raise ValueError("no sample holds a verified minimum: nothing to group")
    pairs = [(k, c[0], c[1]) for k, c in enumerate(kept) if len(c) >= 2]
    mass = mesh.mass_matrix.diagonal()
    if not pairs:  # one branch: the lowest minimum at each sample
        u, t, side_of = np.zeros_like(mesh.V), np.zeros(1 + mesh.V.shape[1] * len(shape.P_moving)), {}
    else:
        u = separating_mode(mesh, minima, pairs)

        def score(X):
            return float(np.einsum("v,vc,vc->", mass, X - mesh.V, u))

        t = threshold_plane(
            shape, minima.samples, [(k, score(minima.X[k, a]), score(minima.X[k, b])) for k, a, b in pairs]
        )
        rest_side = 1 if -t[0] >= 0 else -1  # s(x) = 0 at the rest pose, t(P) = t[0]
        side_of = {rest_side: 0, -rest_side: 1}
    members = {0: [], 1: []} if pairs else {0: []}
    conflicts, lowest = 0, np.full(m, -1)
    for k, cs in enumerate(kept):
        seen = set()
        for c in cs:  # lowest first: on a conflict the lower minimum stays
            label = 0
            if pairs:
                above = score(minima.X[k, c]) - plane(t, minima.samples[k], shape.P_moving) >= 0
                label = side_of[1 if above else -1]
            if label in seen:
                conflicts += 1
                continue
            seen.add(label)
            members[label].append((k, c))
            if lowest[k] < 0:
                lowest[k] = label
    sides = {v: s for s, v in side_of.items()} if pairs else {0: 1}
    branches, solver, t0 = [], Solver(mesh, shape.handles, energy=energy), time.process_time()
    for label, pts in members.items():
        ks = np.array([k for k, _ in pts], dtype=np.int64)
        cs = np.array([c for _, c in pts], dtype=np.int64)
        margin = np.array(
            [stability_margin(solver, minima.X[k, c], u if pairs else None) if margins else np.nan for k, c in pts]
        )
        branches.append(Branch(label, ks, minima.X[ks, cs], minima.energy[ks, cs], margin, sides[label]))
    distinct = np.array([len(c) for c in kept])
    third = np.flatnonzero(distinct > 2)
    return Branches(minima.samples, branches, u, t, distinct, conflicts, lowest, time.process_time() - t0, third=third)


def grid_spacing(Q):
    """h: the smallest distance between two samples Q (m, n_moving, d) (flattened); 0 for fewer than two."""
    flat = np.asarray(Q).reshape(len(Q), -1)
    D = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    return float(D[D > 0].min()) if (D > 0).any() else 0.0


def neighbour_pairs(Q, members):
    """(k, j) pairs of neighbouring samples (within 1.01 × the smallest spacing) with k in ``members`` and j not."""
    flat = np.asarray(Q).reshape(len(Q), -1)
    D = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    h = float(D[D > 0].min()) if (D > 0).any() else 0.0
    inside = np.zeros(len(Q), bool)
    inside[members] = True
    return [(int(k), int(j)) for k in np.flatnonzero(inside) for j in np.flatnonzero((D[k] <= 1.01 * h) & ~inside)]


def edge_of_branch(solver, shape, Qa, Qb, Xa, levels):
    """Bisect the segment Qa → Qb for the last Q where the branch of the minimum Xa at Qa still exists.

    Each half step is solved from the minimum at the last Q on the branch (one warm-started solve) and counts as on
    the branch when no vertex moved more than ``FOLLOW_RATIO`` × the handles' step (no jump) and it verified.

    Returns
    -------
    Q : (n_moving, d) numpy array or None
        None when not even the first half step stays on the branch.
    X : (n_vertices, d) numpy array or None
    energy : float
    """
    lo, hi, X_lo, E_lo, moved = Qa, Qb, Xa, np.nan, False
    for _ in range(levels):
        mid = (lo + hi) / 2
        X, E, ok = _solve(solver, shape.targets(mid), X_lo, "local")
        if ok and np.abs(X - X_lo).max() <= FOLLOW_RATIO * np.abs(mid - lo).max():
            lo, X_lo, E_lo, moved = mid, X, E, True
        else:
            hi = mid
    return (lo, X_lo, E_lo) if moved else (None, None, np.nan)


def refine_folds(shape, branches, levels=4, energy="sarap"):
    """Branches with one more minimum per edge of each branch's domain, bisected towards its fold.

    For every pair of neighbouring samples where a branch has a minimum at one and not at the other (its fold, or
    where a continuation left it, lies between), :func:`edge_of_branch` continues the minimum towards the other
    sample in ``levels`` bisection steps (to 2^-levels of the spacing) and the last minimum on the branch joins it,
    with its energy and stability margin. The fitted λ²_b then crosses zero next to the fold instead of being
    extrapolated over a whole spacing (plank_3d, 17 × 17: λ² is concave there, and the extrapolated fold came
    0.013 early, 3 path steps).

    Returns
    -------
    Branches
        The samples extended by the new configurations (each on one branch only; ``distinct`` 1 and ``lowest``
        that branch there).
    """
    levels = opt.integer("levels", levels, minimum=1, maximum=12)
    if len(branches.branches) < 2:
        return branches
    solver, Q = Solver(shape.mesh, shape.handles, energy=energy), branches.samples
    extra_Q, out, lowest = [], [], []
    t0 = time.process_time()
    for b in branches.branches:
        at = {int(k): i for i, k in enumerate(b.samples)}
        found = []
        for k, j in neighbour_pairs(Q, b.samples):
            q, X, E = edge_of_branch(solver, shape, Q[k], Q[j], b.X[at[k]], levels)
            if q is not None:
                found.append((q, X, E, stability_margin(solver, X, branches.mode)))
        idx = len(Q) + len(extra_Q) + np.arange(len(found), dtype=np.int64)
        extra_Q += [f[0] for f in found]
        lowest += [b.label] * len(found)
        grow = [np.array([f[i] for f in found]).reshape((-1, *b.X.shape[1:]) if i == 1 else -1) for i in (1, 2, 3)]
        out.append(
            Branch(
                b.label,
                np.concatenate([b.samples, idx]),
                np.concatenate([b.X, grow[0]]),
                np.concatenate([b.energy, grow[1]]),
                np.concatenate([b.margin, grow[2]]),
                b.side,
            )
        )
    seconds = time.process_time() - t0
    samples = np.concatenate([Q, np.reshape(extra_Q, (-1, *Q.shape[1:]))])
    return dataclasses.replace(
        branches,
        samples=samples,
        branches=out,
        distinct=np.concatenate([branches.distinct, np.ones(len(extra_Q), int)]),
        lowest=np.concatenate([branches.lowest, lowest]).astype(branches.lowest.dtype),
        margin_seconds=branches.margin_seconds + seconds,
    )


def plane(t, Q, P):
    """t(Q) = t[0] + t[1:] · (Q − P): the threshold at Q (n_moving, d)."""
    return float(t[0] + t[1:] @ (np.asarray(Q) - P).ravel())


def threshold_plane(shape, samples, pairs):
    """t (1 + d n_moving,): the least-squares plane t(Q) through the midpoints of the coexisting minima's scores.

    Parameters
    ----------
    pairs : list of (k, s_a, s_b)
        Sample index and the two minima's scores.
    """
    A = np.array([np.concatenate([[1.0], (samples[k] - shape.P_moving).ravel()]) for k, _, _ in pairs])
    y = np.array([(a + b) / 2 for _, a, b in pairs])
    return np.linalg.lstsq(A, y, rcond=None)[0]


# --------------------------------------------------------------------------- fitting
def _at_train(op, branch_values, rest_value, samples):
    """Values aligned with ``op.train_samples`` (the rest pose first; samples at rest dropped, as :func:`fit`)."""
    at_rest = np.abs(samples - op.P).reshape(len(samples), -1).max(axis=1) <= 1e-14
    return np.concatenate([[rest_value], np.asarray(branch_values, float)[~at_rest]])


def fit_branched(shape, branches, energy="sarap", basis="tps", spatial="hat", k=100, **kw):
    """One DefOp per branch (problem (8) on its samples) with E_b and λ²_b in closed form: a BranchedOperator.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    branches : Branches
    energy : str
        The energy the minima minimise (for λ_min at the rest pose and the metadata).
    basis, spatial, k, **kw
        As :func:`defop.operator.fit.fit`.

    Returns
    -------
    defop.operator.branched.BranchedOperator
    """
    solver = Solver(shape.mesh, shape.handles, energy=energy)
    old_model = any(b.folds is None for b in branches.branches)
    lam_rest = old_model and stability_margin(
        solver, shape.mesh.V, branches.mode if len(branches.branches) > 1 else None
    )
    out = []
    user_meta = kw.pop("meta", None) or {}  # every branch's operator carries the caller's meta
    grid = branches.samples[: branches.grid] if branches.grid else branches.samples
    for b in branches.branches:
        Q = branches.samples[b.samples]
        meta = {"energy": energy, "branch": b.label, **user_meta}
        op = fit_shape(shape, Q, b.X, basis, spatial, k, meta=meta, **kw)
        e = fit_values(op, _at_train(op, b.energy, 0.0, Q))
        if b.folds is None:  # format 1's domain: λ²_b fitted on b's own samples
            lam = fit_values(op, _at_train(op, np.asarray(b.margin) ** 2, lam_rest**2, Q))
            out.append(OperatorBranch(b.label, op, e, lam, b.side))
            continue
        points, values = domain_values(grid, b.samples[b.samples < len(grid)], b.folds, b.segments)
        domain = fit_domain(op.P, op.handle_basis.scale, points, values)
        out.append(OperatorBranch(b.label, op, e, None, b.side, domain=domain))
    meta = {"shape": shape.name, "energy": energy, "conflicts": branches.conflicts}
    box = box_of(shape.P_moving, grid, grid_spacing(grid)) if branches.grid else None
    return BranchedOperator(out, branches.mode, branches.threshold, meta, box=box)


def fit_single(shape, minima, energy="sarap", basis="tps", spatial="hat", k=100):
    """The single-valued fit: problem (8) on the lowest verified minimum at each sample (the training of today)."""
    E = np.where(minima.converged, minima.energy, np.inf)
    ok = np.isfinite(E).any(axis=1)
    c = np.argmin(E, axis=1)
    ks = np.flatnonzero(ok)
    return fit_shape(shape, minima.samples[ks], minima.X[ks, c[ks]], basis, spatial, k, meta={"energy": energy})
