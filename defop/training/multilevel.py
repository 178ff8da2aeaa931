"""Multilevel training (issue 36): each sample's minimum is decided on a coarse mesh and refined once on the fine one.

The policy, beside the one-level policy of :func:`defop.training.bootstrap.train` (``policy="full"``):

1. **Coarse portfolio.** On a coarse mesh of the same shape with the same handles
   (:func:`defop.geometry.multilevel.coarse_mesh_of`: Triangle from the same outline at about 1/:data:`COARSE_FACTOR`
   of the vertices), every sample runs main's start portfolio: the rest pose and the prediction of a linear fit to
   the first dn + 1 samples, then ``rounds - 1`` rounds from the prediction of a smooth fit. Every local solve's
   end point is kept (not only the lowest).
2. **One fine run.** The lowest verified coarse minimum is prolongated (barycentric, rest pose to rest pose and
   handles to handles exactly: :func:`defop.geometry.multilevel.prolongate`) and the fine mesh gets one local
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
   * ``"iterations"``: the fine run takes more than :data:`MAX_FINE_ITERATIONS` Newton iterations.

   The constants are fixed for every shape; none depends on running statistics.

``policy="auto"`` (the default of ``train``) takes this path for meshes of at least :data:`AUTO_VERTICES`
vertices. Where no coarse mesh exists (a 3D mesh: the coarse Kuhn grid is not built yet; a mesh without an
outline; a coarse mesh that would lose a part or a handle), training runs on one level and says so in
``record.multilevel["fallback"]``, and with a :class:`MultilevelWarning` when ``"multilevel"`` was asked for.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np
import scipy.sparse as sp

from .. import options as opt
from ..geometry.multilevel import CoarseningError, coarse_mesh_of, prolongate
from ..operator import handle_bases as hb
from ..operator.fit import fit
from ..scene.shapes import Shape
from ..variational import energies as en
from ..variational.solver import NotConvergedWarning, Solver
from . import batch

__all__ = [
    "AUTO_VERTICES",
    "COARSE_FACTOR",
    "MARGIN",
    "MAX_FINE_ITERATIONS",
    "MultilevelWarning",
    "POLICIES",
    "RULES",
    "Levels",
    "choose",
    "coarse_portfolio",
    "constants",
    "refine",
]

#: the policies of ``train(policy=...)``
POLICIES = ("full", "multilevel", "auto")
#: ``policy="auto"`` trains on two levels from this many fine vertices on. Kept above every catalogue model, so the
#: lessons' ground truth is main's. Measured (benchmarks/README.md, bench_multilevel): multilevel took 1.8-2.2x fewer
#: CPU s than main at 596-3,910 vertices (m = 200, no sample higher, 2 of 200 aleph samples lower), 2.23x at 9,873
#: and 1.28x at 29,739 (m = 40): lowering this constant is the lever, and it needs the main job re-run.
AUTO_VERTICES = 10_000
#: the coarse mesh has about n / COARSE_FACTOR vertices ...
COARSE_FACTOR = 8
#: ... and at least this many
MIN_COARSE_VERTICES = 150
#: safeguard "margin": two distinct coarse minima within this relative energy of each other
MARGIN = 0.05
#: coarse minima farther apart than this fraction of the bounding-box diagonal (any vertex) are distinct
DISTINCT = 1e-3
#: safeguard "iterations": a fine run from a prolongated coarse minimum taking more Newton iterations than this
MAX_FINE_ITERATIONS = 40
#: the safeguard's rules, in the order they are checked ("" in a record: none fired)
RULES = ("coarse", "margin", "rank", "flip", "unverified", "iterations")


class MultilevelWarning(UserWarning):
    """Multilevel training was asked for (or chosen by ``auto``) but runs on one level: no coarse mesh exists."""


def constants():
    """The policy's constants, for the cache keys and the operator's metadata (dict)."""
    return dict(
        auto_vertices=AUTO_VERTICES,
        coarse_factor=COARSE_FACTOR,
        min_coarse_vertices=MIN_COARSE_VERTICES,
        margin=MARGIN,
        distinct=DISTINCT,
        max_fine_iterations=MAX_FINE_ITERATIONS,
    )


@dataclasses.dataclass
class Levels:
    """A fine shape and its coarse level.

    Attributes
    ----------
    fine, coarse : defop.scene.shapes.Shape
        The same handles (same rest positions, same order, same moving flags) on both meshes.
    P : (n, n_c) scipy.sparse.csr_matrix
        The prolongation (:func:`defop.geometry.multilevel.prolongation`).
    """

    fine: Shape
    coarse: Shape
    P: sp.csr_matrix

    def prolongate(self, Xc):
        """(n_c, d) coarse map -> (n, d) fine map: rest to rest and handles to handles exactly."""
        return prolongate(self.P, self.fine.mesh.V, self.coarse.mesh.V, Xc, self.fine.handles, self.coarse.handles)


def levels(shape):
    """The :class:`Levels` of a shape; :class:`~defop.geometry.multilevel.CoarseningError` where none exists."""
    mesh, idx, P = coarse_mesh_of(shape.mesh, shape.outline, shape.P, COARSE_FACTOR, MIN_COARSE_VERTICES)
    coarse = Shape(f"{shape.name} (coarse)", mesh, idx, shape.moving.copy(), list(shape.regions), shape.description)
    return Levels(shape, coarse, P)


def choose(shape, policy):
    """The policy that runs for ``shape``: ``(used, levels or None, why)``.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    policy : str
        One of :data:`POLICIES`.

    Returns
    -------
    used : str
        ``"full"`` or ``"multilevel"``.
    levels : Levels or None
    why : str
        Why one level runs where two were asked for (or chosen by ``auto``); "" otherwise.
    """
    opt.choice("policy", policy, POLICIES)
    n = shape.mesh.n_vertices
    if policy == "full":
        return "full", None, ""
    if policy == "auto" and n < AUTO_VERTICES:
        return "full", None, f"auto: {n} vertices, fewer than {AUTO_VERTICES}"
    try:
        lv = levels(shape)
    except CoarseningError as exc:  # asked for: a warning; chosen by auto: the record says it (no noise in lessons)
        if policy == "multilevel":
            warnings.warn(f"multilevel training of {shape.name!r} runs on one level: {exc}", MultilevelWarning, 3)
        return "full", None, str(exc)
    return "multilevel", lv, ""


def _local_runs(solver, jobs):
    """Per job (targets, starts, rest): one local solve per start that is not None and from the rest pose if
    ``rest``; every end point as (X, energy, converged)."""
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for T, starts, rest in jobs:
            runs = [solver.solve_best(T, starts=[X0], rest=False) for X0 in starts if X0 is not None]
            runs += [solver.solve_best(T, rest=True)] if rest else []
            out.append([(r.X, float(r.energy), bool(r.converged)) for r in runs])
    return out


def _winner(candidates):
    """The lowest verified end point (the lowest of all when none verified): ``Solver.solve_best``'s rule."""
    return min(candidates, key=lambda c: (not c[2], c[1] if np.isfinite(c[1]) else np.inf))


def coarse_portfolio(lv, samples, energy, n_jobs=None, progress=True, rounds=2):
    """Main's start portfolio on the coarse mesh, keeping every end point.

    Parameters
    ----------
    lv : Levels
    samples : (m, n, d) numpy array
    energy : str
    n_jobs : int, optional
    progress : bool
    rounds : int

    Returns
    -------
    candidates : list of m lists of (X (n_c, d), energy, converged)
    """
    cs = lv.coarse
    mesh, d, m = cs.mesh, cs.mesh.dim, len(samples)
    solver = Solver(mesh, cs.handles, energy)
    T = [cs.targets(q) for q in samples]
    run = functools.partial(_local_runs, solver)
    nb = min(m, d * cs.n_moving + 1)
    cands = batch.parallel_map(run, [(T[i], [], True) for i in range(nb)], n_jobs, progress, "coarse bootstrap")
    meta = {"shape": cs.name, "energy": energy}
    if m > nb:
        X = np.array([_winner(c)[0] for c in cands])
        lin = fit(mesh, cs.handles, cs.moving, samples[:nb], X, "linear", "hat", meta=meta)
        starts = batch.warm_starts(lin, samples[nb:], mesh, energy)
        cands += batch.parallel_map(
            run, [(T[nb + i], [s], True) for i, s in enumerate(starts)], n_jobs, progress, "coarse solves"
        )
    for _ in range(rounds - 1):
        X = np.array([_winner(c)[0] for c in cands])
        smooth = "quadratic" if m + 1 >= hb.basis_size("quadratic", cs.n_moving, d=d) else "linear"
        inter = fit(mesh, cs.handles, cs.moving, samples, X, smooth, "hat", meta=meta)
        starts = batch.warm_starts(inter, samples, mesh, energy)
        more = batch.parallel_map(
            run, [(t, [s], False) for t, s in zip(T, starts)], n_jobs, progress, "coarse re-solves"
        )
        cands = [a + b for a, b in zip(cands, more)]
    return cands


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
        iters = int(single.iterations)
        rule = "unverified" if not single.converged else "iterations" if iters > MAX_FINE_ITERATIONS else ""
        if not rule:
            return single.X, True, "", iters, len(minima), minima[0][1]
        single = single if single.converged else None
    barrier = en.is_barrier(solver.energy)
    ok = [S for S in starts if not (barrier and np.any(lv.fine.mesh.flipped(S)))]
    best = solver.solve_best(T, starts=ok, rest=True)  # the full fine portfolio
    if single is not None and (not best.converged or single.energy <= best.energy):
        best = single  # the verified single run competes as it is
    return best.X, bool(best.converged), rule, iters, len(minima), minima[0][1] if minima else np.nan


def _refine_chunk(lv, solver, jobs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        return [refine_one(lv, solver, T, c) for T, c in jobs]


_FIELDS = ("X", "converged", "rule", "iterations", "minima", "coarse_energy")


def _chunk_cache(checkpoint, key_of, n, d):
    """``map_checkpointed``'s chunk callable for :func:`refine`: every field of a chunk's results in one entry."""
    if checkpoint is None:
        return None
    expect = lambda k: {  # noqa: E731
        "X": ((k, n, d), "f"),
        "converged": ((k,), "b"),
        "rule": ((k,), "i"),
        "iterations": ((k,), "i"),
        "minima": ((k,), "i"),
        "coarse_energy": ((k,), "f"),
    }

    def chunk(a, b, compute):
        def arrays():
            res = compute()
            cols = list(zip(*res))
            return {
                "X": np.array(cols[0]),
                "converged": np.array(cols[1], bool),
                "rule": np.array([RULES.index(r) + 1 if r else 0 for r in cols[2]]),
                "iterations": np.array(cols[3], int),
                "minima": np.array(cols[4], int),
                "coarse_energy": np.nan_to_num(np.array(cols[5], float), nan=-1.0),
            }

        got = checkpoint.load_or_compute(key_of(a, b), expect(b - a), arrays)
        rules = ["" if r == 0 else RULES[r - 1] for r in got["rule"]]
        return list(zip(got["X"], got["converged"], rules, got["iterations"], got["minima"], got["coarse_energy"]))

    return chunk


def refine(lv, samples, energy, candidates, n_jobs=None, progress=True, checkpoint=None, key_of=None):
    """The fine stage of every sample (:func:`refine_one`), in parallel and checkpointed.

    Parameters
    ----------
    lv : Levels
    samples : (m, n, d) numpy array
    energy : str
    candidates : list of m lists
        :func:`coarse_portfolio`'s.
    checkpoint : defop.training.batch.Checkpoints, optional
    key_of : callable, optional
        ``key_of(a, b)``: the checkpoint key of samples a..b (everything that determines them).

    Returns
    -------
    X : (m, n, d) numpy array
    converged : (m,) bool numpy array
    info : dict
        Per sample: ``rule`` (str, "" when the safeguard did not fire), ``iterations`` (the single fine run's),
        ``minima`` (distinct verified coarse minima), ``coarse_energy``.
    """
    fine = lv.fine
    solver = Solver(fine.mesh, fine.handles, energy)
    jobs = [(fine.targets(q), c) for q, c in zip(samples, candidates)]
    n, d = fine.mesh.V.shape
    chunk = None if key_of is None else _chunk_cache(checkpoint, key_of, n, d)
    res = batch.map_checkpointed(
        functools.partial(_refine_chunk, lv, solver), jobs, n_jobs, progress, "fine runs", chunk
    )
    cols = list(zip(*res))
    info = {
        "rule": [str(r) for r in cols[2]],
        "iterations": [int(i) for i in cols[3]],
        "minima": [int(k) for k in cols[4]],
        "coarse_energy": [float(e) for e in cols[5]],
    }
    return np.array(cols[0]), np.array(cols[1], bool), info
