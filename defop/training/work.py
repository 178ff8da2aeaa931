"""The work of a training's solves: a deterministic measure of its cost, counted from symbolic data.

A sample's work is what its factorisations cost in factor nonzeros (:mod:`defop.variational.work`, read where the
sample runs); each distinct solver (one handle set on one mesh) adds its setup once: its bi-Laplacian's LU (the
rest pose's start, its LU's nonzeros), its ordering and symbolic analysis (:data:`SETUP` factorisations' worth) and
the rest of its construction (:data:`SOLVER` per unknown); a joint sample adds its draw (:data:`DRAW`,
:func:`defop.training.movable_budget.train_within`). None depends on
the machine's speed, its load, the number of workers or which solvers a worker happened to keep, so a budget
counted in work (:func:`defop.training.movable_budget.train_within`) picks the same m wherever the same back end runs
the same solves. It does depend on the back end (PARDISO and qdldl give different factor nonzeros), on whether
factorisations are re-used (``DEFOP_REUSE``: CG steps are not counted) and on the constants :data:`SETUP`,
:data:`SOLVER`, :data:`~defop.variational.work.ITERATION` and :data:`~defop.variational.work.HESSIAN`:
:func:`units` describes them, kept with every work recorded, and work in other units is not compared. A sample
loaded from a checkpoint has no work (NaN): its solves did not run here.
"""

from __future__ import annotations

import contextlib

import numpy as np

from ..variational import backend as bk
from ..variational import work as counter

__all__ = [
    "DRAW",
    "SETUP",
    "SOLVER",
    "VERSION",
    "Tally",
    "count",
    "first_of",
    "prefix",
    "reading",
    "setup_of",
    "solver_key",
    "tally",
    "units",
]

#: a solver's construction beside its factorisations, per unknown (n d) of its mesh, in factor nonzeros: the
#: problem's set-up, the bi-Laplacian's slicing and ordering, qdldl's ordering and symbolic analysis, all growing
#: with the mesh. Fitted once to the per-placement CPU of the bar's and the aleph's joint trainings at full size (4.9
#: and 23 ms a placement: 309 and 295 a vertex; one factor nonzero is about 20 ns); held out, the octopus's 34.8 ms
#: was counted as 34.4 (benchmarks/README.md, 2026-12-02, sixth part). Before (SETUP 3 factorisations, no term per
#: unknown) the aleph's 850 placements were counted at about half their CPU.
SOLVER = 150.0

#: a solver's ordering and symbolic analysis, in factorisations of its Hessian (counted with :data:`SOLVER`)
SETUP = 1.0

#: drawing one joint (P, Q) sample (:func:`defop.training.movable.sample_joint`: the shape at its placement, its
#: regions, its Q), in factor nonzeros: measured 0.37 ms a sample on the bar and 0.55 on the aleph, 3% and 0.5% of
#: their joint trainings' CPU (the geometric mean, at 20.3 ns a unit; held out, the octopus's 9 handles took 1.2 ms:
#: 0.5% of its). A fixed-P training's 200 draws are not counted.
DRAW = 22_000.0

#: the rule's version: bumped when what is counted changes (a work recorded under another version is not compared;
#: 2: :data:`~defop.variational.work.HESSIAN`, :data:`SOLVER`, :data:`DRAW`, ITERATION 14,000 and SETUP 1, 2026-12-02
#: sixth part)
VERSION = 2


def units(mesh):
    """The units a training's work on ``mesh`` is counted in, here and now: the back end its solves use
    (:func:`defop.variational.backend.choose_backend`, ``DEFOP_BACKEND``), whether they re-use factorisations
    (``DEFOP_REUSE``, at the mesh's unknowns), :data:`~defop.variational.work.ITERATION`,
    :data:`~defop.variational.work.HESSIAN`, :data:`SETUP`, :data:`SOLVER`, :data:`DRAW` and :data:`VERSION`. Two
    works compare only in equal units."""
    name = bk.choose_backend(None, mesh.n_vertices, mesh.dim)
    reuse = bool(bk.choose_reuse(mesh.n_vertices * mesh.dim, name))
    return {
        "backend": name,
        "reuse": reuse,
        "iteration": float(counter.ITERATION),
        "hessian": float(counter.HESSIAN),
        "setup": SETUP,
        "solver": SOLVER,
        "draw": DRAW,
        "version": VERSION,
    }


def recorded(meta, mesh):
    """The work kept in a cached truth's ``meta`` (``"work"``), NaN unless it is there in this run's
    :func:`units` (``"work_units"``): a truth cached without its units, or in others, has no work here."""
    done = meta.get("work")
    if done is None or meta.get("work_units") != units(mesh):
        return float("nan")
    return float(done)


def setup_of(solver):
    """The setup work of a solver (:class:`defop.variational.solver.Solver`): its bi-Laplacian's LU nonzeros (0 until
    a solve from the rest pose built it), :data:`SETUP` times its Hessian factor's nonzeros and :data:`SOLVER` times
    its mesh's unknowns (n d); 0 for a stand-in without a ``problem`` (a test's solver double: it factorises
    nothing)."""
    p = getattr(solver, "problem", None)
    if p is None:
        return 0.0
    unknowns = p.mesh.n_vertices * p.mesh.dim
    return float(p.biharmonic_nnz + SETUP * (p.hessian.factor_nnz or 0) + SOLVER * unknowns)


def solver_key(mesh, handles):
    """What identifies a solver's setup: its mesh's vertex count and its handles (bytes)."""
    return (int(mesh.n_vertices), np.asarray(handles, np.int64).tobytes())


class Tally:
    """The work of every batch solved while it is open (:func:`tally`): the samples' factorisations and each
    distinct solver's setup once (the largest seen: one that never solved from the rest pose built no LU)."""

    def __init__(self):
        self.factor, self.setups = 0.0, {}

    def add(self, work, setup, keys):
        self.factor += float(np.sum(work))
        for k, s in zip(keys, setup):
            self.setups[k] = max(self.setups.get(k, 0.0), float(s))

    @property
    def total(self):
        """The work so far: NaN where a sample was loaded from a checkpoint."""
        return self.factor + float(sum(self.setups.values()))


_OPEN = []


@contextlib.contextmanager
def tally():
    """A :class:`Tally` of the batches solved in this block (:func:`count`)."""
    t = Tally()
    _OPEN.append(t)
    try:
        yield t
    finally:
        _OPEN.remove(t)


def count(work, setup, keys):
    """Count a batch's per-sample work (m,), its solvers' setup (m,) and their keys (m,) in every open tally."""
    for t in _OPEN:
        t.add(work, setup, keys)


def first_of(idx):
    """(m,) bool: sample k is the first of its placement (``idx`` (m, b) int: each sample's rest vertices), where a
    placement's solver setup is counted, once."""
    first = np.zeros(len(idx), bool)
    first[np.unique(np.asarray(idx), axis=0, return_index=True)[1]] = True
    return first


def prefix(work, setup, first):
    """(m,) the work of the first 1, 2, ..., m samples: their factorisations and the setup of each solver where it
    is first met (``first`` (m,) bool: sample k is the first of its solver)."""
    work, setup = np.asarray(work, float), np.asarray(setup, float)
    return np.cumsum(work + np.where(first, setup, 0.0))


def reading():
    """This process's factorisation work so far (:func:`defop.variational.work.total`)."""
    return counter.total()
