"""Multilevel training: each sample's minimum is decided on a coarse mesh and refined once on the fine one.

The policy, beside the one-level policy of :func:`defop.training.bootstrap.train` (``policy="full"``):

1. **Coarse portfolio.** On a coarse mesh of the same shape with the same handles
   (:func:`defop.geometry.coarse.coarse_mesh_of`: Triangle from the same outline at about 1/:data:`COARSE_FACTOR`
   of the vertices; a tetrahedral mesh gets Kuhn cubes at twice its spacing, the handles inserted as vertices),
   every sample runs the full policy's start portfolio (the same code,
   :func:`defop.training.portfolios.portfolio`): the rest pose and the prediction of a linear fit to
   the first dn + 1 samples, then ``rounds - 1`` rounds from the prediction of a smooth fit. Every local solve's
   end point is kept (not only the lowest).
2. **One fine run.** The lowest verified coarse minimum is prolongated (barycentric, rest pose to rest pose and
   handles to handles exactly: :func:`defop.geometry.coarse.prolongate`) and the fine mesh gets one local
   Newton run from it, which must verify.
3. **Safeguard.** A sample falls back to the full fine portfolio (the rest pose and every prolongated coarse
   minimum, the lowest verified minimum kept; a verified fine run competes as it is) when one of the
   :data:`RULES` holds, checked in this order:

   * ``"coarse"``: no coarse start verified;
   * ``"margin"``: the two lowest distinct coarse minima are within :data:`MARGIN` (relative) of each other;
   * ``"rank"``: the fine energies of the prolongated coarse minima (evaluations, not solves) rank them
     differently from their coarse energies;
   * ``"flip"``: the prolongated winner flips a fine element;
   * ``"unverified"``: the fine run does not end on a verified minimum;
   * ``"iterations"``: the fine run takes more than :data:`MAX_FINE_ITERATIONS` Newton iterations;
   * ``"rest"``: the fine run ends higher (by more than :data:`REST_TOLERANCE`, relative) than the rest pose's
     start at the targets (:func:`rest_start_energy`: the rest pose with the handles' moves extended biharmonically,
     the first step of the continuation that the full policy's rest-pose solve takes). Where that step is admissible
     (a barrier energy: no element flipped) and taken whole, the rest-pose solve is a Newton descent from it and ends
     no higher than its energy: the single run would then certainly end above a minimum the full policy finds. One
     back-substitution and one energy evaluation per sample; a sufficient check, not a certificate (the full policy's
     other starts, and a rest-pose solve that needs several continuation stages, are not bounded by it).

   The constants are fixed for every shape; none depends on running statistics.

``policy="auto"`` (the default of ``train``) takes this path wherever a coarse mesh exists (:func:`has_coarse_level`,
in 2D and 3D, at every size: :data:`AUTO_VERTICES` is 0). Where none exists (a planar mesh without an outline; a mesh
too small to save anything; a coarse mesh that would lose a part, such as a limb thinner than the coarse spacing, or a
handle), training runs on one level and says so in ``record.multilevel["fallback"]``, and with a
:class:`MultilevelWarning` when ``"multilevel"`` was asked for.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .. import options as opt
from ..geometry.coarse import CoarseningError, coarse_mesh_of, prolongate
from ..lazy import renamed
from ..scene.shapes import Shape
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning

__all__ = [
    "AUTO_VERTICES",
    "COARSE_FACTOR",
    "MARGIN",
    "MAX_FINE_ITERATIONS",
    "OUTLINE_REACH",
    "REST_TOLERANCE",
    "MultilevelWarning",
    "POLICIES",
    "RULES",
    "CoarseLevel",
    "choose",
    "coarse_level",
    "coarse_portfolio",
    "coarse_constants",
    "has_coarse_level",
    "outline_neighbours",
    "constants",
    "refine",
    "rest_start_energy",
]

#: the policies of ``train(policy=...)``
POLICIES = ("full", "multilevel", "auto")
#: ``policy="auto"`` trains on two levels from this many fine vertices on (wherever a coarse mesh exists): 0, every
#: size. Measured (benchmarks/README.md, bench_multilevel, bench_training): multilevel took 1.8-2.2x fewer CPU s than
#: the full policy at 596-3,910 vertices, 2.23x at 9,873 and 1.28x at 29,739; at aleph m = 200 4.18x
#: fewer than d79f472 at held-out error ratio 1.008 / 1.054 against the reference truth (two seeds, 300 Q each), every
#: sample verified, none higher than the full policy's minimum, 2 of 200 lower. Not a guarantee: at 794 aleph vertices
#: (m = 300, seed 0) one sample of 300 ends 9.5% above the full policy's minimum, the fine rest-pose one, which only
#: that solve finds (the coarse portfolio has one minimum there, the single run verifies, no rule fires); 3 end lower.
AUTO_VERTICES = 0
#: the coarse mesh has about n / COARSE_FACTOR vertices ...
COARSE_FACTOR = 8
#: ... and at least this many
MIN_COARSE_VERTICES = 150
#: a movable handle's coarse level also keeps the fine boundary vertices within this many coarse spacings of where
#: the handle may sit (:func:`outline_neighbours`)
OUTLINE_REACH = 2.0
#: safeguard "margin": two distinct coarse minima within this relative energy of each other
MARGIN = 0.05
#: coarse minima farther apart than this fraction of the bounding-box diagonal (any vertex) are distinct
DISTINCT = 1e-3
#: safeguard "iterations": a fine run from a prolongated coarse minimum taking more Newton iterations than this
MAX_FINE_ITERATIONS = 40
#: safeguard "rest": the fine run ending higher than the rest pose's start at the targets by more than this (relative)
REST_TOLERANCE = 1e-6
#: the safeguard's rules, in the order they are checked ("" in a record: none fired)
RULES = ("coarse", "margin", "rank", "flip", "unverified", "iterations", "rest")


class MultilevelWarning(UserWarning):
    """Multilevel training was asked for (or chosen by ``auto``) but runs on one level: no coarse mesh exists."""


def coarse_constants():
    """The constants that decide the coarse level and which coarse minima are distinct (dict): the key of what
    depends on the coarse portfolio alone (:mod:`defop.training.reference`), not on the safeguard."""
    return {"coarse_factor": COARSE_FACTOR, "min_coarse_vertices": MIN_COARSE_VERTICES, "distinct": DISTINCT}


def constants():
    """The policy's constants, for the cache keys and the operator's metadata (dict)."""
    return {
        **coarse_constants(),
        "rules": RULES,
        "margin": MARGIN,
        "max_fine_iterations": MAX_FINE_ITERATIONS,
        "rest_tolerance": REST_TOLERANCE,
    }


@dataclasses.dataclass
class CoarseLevel:
    """A fine shape and its coarse level (the multilevel policy's two meshes).

    Attributes
    ----------
    fine, coarse : defop.scene.shapes.Shape
        The same handles (same rest positions, same order, same moving flags) on both meshes.
    P : (n, n_c) scipy.sparse.csr_matrix
        The prolongation (:func:`defop.geometry.coarse.prolongation`).
    """

    fine: Shape
    coarse: Shape
    P: sp.csr_matrix
    #: (k,) int numpy array: the fine vertices that are coarse vertices too (the handles, and with ``vertices`` given
    #: to :func:`coarse_level` every vertex a handle may be placed at), sorted; and (k,) the coarse vertex of each
    fine_vertices: np.ndarray = None
    coarse_vertices: np.ndarray = None

    def prolongate(self, Xc):
        """(n_c, d) coarse map -> (n, d) fine map: rest to rest and handles to handles exactly."""
        return prolongate(self.P, self.fine.mesh.V, self.coarse.mesh.V, Xc, self.fine.handles, self.coarse.handles)

    def coarse_of(self, vertices):
        """(k,) int numpy array: the coarse vertex at each fine vertex of ``vertices`` (k,) (the same rest position).

        Raises
        ------
        ValueError
            A vertex that is not a coarse vertex (not among :attr:`fine_vertices`).
        """
        v = np.asarray(vertices, np.int64)
        pos = np.clip(np.searchsorted(self.fine_vertices, v), 0, len(self.fine_vertices) - 1)
        bad = v[self.fine_vertices[pos] != v]
        if len(bad):
            raise ValueError(f"fine vertex {int(bad[0])} is not a vertex of the coarse mesh (no handle may sit there)")
        return self.coarse_vertices[pos]

    def at(self, handles):
        """The same two meshes with the handles at fine vertices ``handles`` (h,) and at their coarse vertices (a
        movable handle placed: :func:`coarse_level` with ``vertices`` holding them)."""
        fine = dataclasses.replace(self.fine, handles=handles)
        return dataclasses.replace(
            self, fine=fine, coarse=dataclasses.replace(self.coarse, handles=self.coarse_of(handles))
        )


def coarse_level(shape, vertices=None):
    """The :class:`CoarseLevel` of a shape; :class:`~defop.geometry.coarse.CoarseningError` where none exists.

    ``vertices`` ((k,) int, optional): fine vertices that become coarse vertices too, beside the handles (where a
    movable handle may sit: :meth:`CoarseLevel.at` then places the handles on both meshes).
    """
    extra = np.setdiff1d(outline_neighbours(shape.mesh, vertices), shape.handles)
    points = np.concatenate([shape.P, shape.mesh.V[extra]])
    h = len(shape.handles)
    ok = np.full(len(points), vertices is not None)  # a fixed-P training's handles on the outline: no coarse level
    mesh, idx, P = coarse_mesh_of(shape.mesh, shape.outline, points, COARSE_FACTOR, MIN_COARSE_VERTICES, ok)
    coarse = Shape(f"{shape.name} (coarse)", mesh, idx[:h], shape.moving.copy(), list(shape.regions), shape.description)
    kept = np.concatenate([shape.handles, extra])
    order = np.argsort(kept)
    return CoarseLevel(shape, coarse, P, kept[order], np.asarray(idx, np.int64)[order])


def outline_neighbours(mesh, vertices):
    """``vertices`` (k,) and, on a planar mesh, the boundary vertices within :data:`OUTLINE_REACH` coarse spacings
    (about sqrt(:data:`COARSE_FACTOR`) fine edges) of one of them, sorted (an empty array for None): the coarse
    outline then runs through the fine one around them, so a vertex near the boundary is not cut off by a coarse
    chord."""
    v = np.unique(np.asarray([] if vertices is None else vertices, np.int64))
    if not len(v) or mesh.dim != 2:
        return v
    B = np.asarray(mesh.boundary_vertices, np.int64)
    E = mesh.F[:, [0, 1]]
    edge = float(np.median(np.linalg.norm(mesh.V[E[:, 0]] - mesh.V[E[:, 1]], axis=1)))
    reach = OUTLINE_REACH * np.sqrt(COARSE_FACTOR) * edge
    near = cKDTree(mesh.V[v]).query(mesh.V[B], distance_upper_bound=reach)[0] <= reach
    return np.union1d(v, B[near])


def has_coarse_level(shape):
    """Whether the shape has a coarse level (:func:`coarse_level` succeeds), in 2D or 3D (bool)."""
    try:
        coarse_level(shape)
    except CoarseningError:
        return False
    return True


def choose(shape, policy, vertices=None):
    """The policy that runs for ``shape``: ``(used, level or None, why)``.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    policy : str
        One of :data:`POLICIES`.
    vertices : (k,) int numpy array, optional
        Fine vertices the coarse mesh must hold beside the handles (:func:`coarse_level`).

    Returns
    -------
    used : str
        ``"full"`` or ``"multilevel"``.
    level : CoarseLevel or None
    why : str
        Why one level runs where two were asked for (or chosen by ``auto``); "" otherwise.
    """
    opt.choice("policy", policy, POLICIES)
    n = shape.mesh.n_vertices
    if policy == "full":
        return "full", None, ""
    if policy == "auto" and n < AUTO_VERTICES:  # a lever kept at 0: every mesh with a coarse mesh
        return "full", None, f"auto: {n} vertices, fewer than {AUTO_VERTICES}"
    try:
        lv = coarse_level(shape, vertices)
    except CoarseningError as exc:  # asked for: a warning; chosen by auto: the record says it (no noise in lessons)
        if policy == "multilevel":
            warnings.warn(f"multilevel training of {shape.name!r} runs on one level: {exc}", MultilevelWarning, 3)
        return "full", None, str(exc)
    return "multilevel", lv, ""


def distinct_minima(candidates, diagonal):
    """The verified candidates, lowest energy first, one per minimum (:data:`DISTINCT` apart, largest coordinate
    difference: :func:`defop.training.minima.distinct_minima` with ``metric="max"``).

    Returns
    -------
    list of (X, energy)
    """
    from .minima import distinct_minima as distinct

    X, E, ok = [c[0] for c in candidates], [c[1] for c in candidates], [bool(c[2]) for c in candidates]
    return [(X[i], E[i]) for i in distinct(X, E, ok, DISTINCT, diagonal, metric="max")]


def _safeguard(lv, solver, minima, starts):
    """The first rule of :data:`RULES` before the fine run that fires ("" for none)."""
    if not minima:
        return "coarse"
    Ec = [E for _, E in minima]
    if len(Ec) > 1 and Ec[1] - Ec[0] <= MARGIN * abs(Ec[0]):
        return "margin"
    if len(Ec) > 1:
        Ef = np.array([solver.energy_of(S) for S in starts])
        if not np.all(np.diff(Ef) > 0):
            return "rank"
    if np.any(lv.fine.mesh.flipped(starts[0])):
        return "flip"
    return ""


def rest_start_energy(solver, T):
    """The energy of the rest pose's start at the targets: the rest pose with the handles' moves extended
    biharmonically (the first continuation step of a solve from the rest pose; +inf where it flips an element under
    a barrier energy).

    Parameters
    ----------
    solver : defop.variational.solver.Solver
    T : (h, d) numpy array
        Targets, one row per handle given to the solver.

    Returns
    -------
    float
    """
    V = solver.mesh.V
    Tu = solver.targets_of(T)
    return float(solver.energy_of(V + solver.extend(Tu - V[solver.handles])))


def _single_rule(solver, T, single):
    """The rule of :data:`RULES` that the single fine run fires ("" for none)."""
    if not single.converged:
        return "unverified"
    if single.iterations > MAX_FINE_ITERATIONS:
        return "iterations"
    bound = rest_start_energy(solver, T)
    return "rest" if single.energy - bound > REST_TOLERANCE * abs(bound) else ""


def refine_one(lv, solver, T, candidates):
    """One sample on the fine mesh: the single run from the prolongated coarse winner, or the safeguard's fallback.

    Returns
    -------
    X : (n, d) numpy array
    converged : bool
    rule : str
        The safeguard rule that fired ("" for none).
    iterations : int
        Newton iterations of the single fine run (0 when a rule fired before it).
    n_minima : int
        Distinct verified coarse minima.
    coarse_energy : float
        The coarse winner's energy (NaN when none verified).
    """
    minima = distinct_minima(candidates, lv.coarse.mesh.bbox_diagonal)
    starts = [lv.prolongate(X) for X, _ in minima]
    rule, iters, single = _safeguard(lv, solver, minima, starts), 0, None
    if not rule:
        single = solver.solve_best(T, starts=[starts[0]], rest=False)
        iters, rule = int(single.iterations), _single_rule(solver, T, single)
        if not rule:
            return single.X, True, "", iters, len(minima), minima[0][1]
    best = _fallback(lv, solver, T, starts, single)
    return best.X, bool(best.converged), rule, iters, len(minima), minima[0][1] if minima else np.nan


def _fallback(lv, solver, T, starts, single):
    """The full fine portfolio: the rest pose and every flip-free prolongated coarse minimum, the lowest verified
    minimum kept (a :class:`~defop.variational.solver.SolveResult`).

    ``single``, the single run from ``starts[0]`` when it ran (else None), is that portfolio's first local solve
    already (a solve is deterministic): it is not run again but competes as it is, first, with the portfolio's
    rule (verified before not, then the lower energy, the earlier on a tie); a verified single run wins a tie."""
    barrier = en.is_barrier(solver.energy)
    ok = [S for S in starts[1 if single is not None else 0 :] if not (barrier and np.any(lv.fine.mesh.flipped(S)))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        rest = solver.solve_best(T, starts=ok, rest=True)  # the rest of the full fine portfolio
    if single is None:
        return rest
    if single.converged and (not rest.converged or single.energy <= rest.energy):
        return single
    return min((single, rest), key=lambda r: (not r.converged, r.energy if np.isfinite(r.energy) else np.inf))


def coarse_portfolio(lv, samples, energy, n_jobs=None, progress=True, rounds=2):
    """Every coarse end point per sample: :func:`defop.training.portfolios.portfolio` on ``lv.coarse``, every end
    point kept (list of m lists of (X, energy, converged))."""
    from . import portfolios

    return portfolios.portfolio(lv.coarse, samples, energy, n_jobs, progress, rounds, keep="all")[4]


def refine(lv, samples, energy, candidates, n_jobs=None, progress=True, checkpoint=None, key_of=None):
    """The fine stage of every sample: (X, converged, info) of :func:`defop.training.portfolios.refine`."""
    from . import portfolios

    return portfolios.refine(lv, samples, energy, candidates, refine_one, RULES, n_jobs, progress, checkpoint, key_of)[
        :3
    ]


__getattr__ = renamed(__name__, {"Levels": "CoarseLevel", "levels": "coarse_level"})
