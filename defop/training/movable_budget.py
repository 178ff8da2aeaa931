"""The budget of a joint training, counted in work: the joint operator D(x; P, Q) that costs what ``factor``
fixed-P trainings cost (issue 44: 5 trainings at m = 200), its m where the count stops.

Work (:mod:`defop.training.work`) is counted from symbolic data: each factorisation's factor nonzeros plus a part
per Hessian nonzero and a fixed part, each distinct solver's setup once, each joint sample's draw, the fit. It is
not time, so the same inputs give the same m and the same operator
wherever the same back end runs the same solves; work in other units (another back end, re-use on or off, other
constants: :func:`defop.training.work.units`) is never compared. It tracks CPU seconds: its constants (a Newton
iteration's fixed part and its part per Hessian nonzero, a solver's construction per unknown, a joint sample's draw,
:data:`FIT_FLOPS`) were fitted once on the bar and the aleph at full size, the octopus held out; a 5.00x work budget
cost 4.84-5.73x (bar, three runs), 5.49x (aleph) and 5.30x (octopus) the CPU seconds: about 5% still unpredicted, a
run's ratio scattering by ±8% at the same work (benchmarks/README.md, 2026-12-02, sixth part; before it 6.03x, 6.23x
and 4.84x). The joint training draws its
samples as one seeded sequence, chunk by chunk (:data:`defop.training.batch.CHUNK` each,
:func:`defop.training.movable.sample_joint` on one generator), solves each chunk (cached) and stops in the chunk
where its work first reaches ``factor`` × the fixed-P training's: m is that sample's place in the sequence, and the
operator is fitted to the first m samples.
"""

from __future__ import annotations

import warnings

import numpy as np

from .. import options as opt
from ..operator.fit import centre_count
from ..variational import energies as en
from . import batch, solves
from . import movable as mv
from . import multilevel as ml
from . import work as work_mod
from .bootstrap import train

__all__ = ["AHEAD", "CAP", "FIT_FLOPS", "budget_work", "fit_work", "reference", "stop_at", "train_within"]

#: the longest joint sequence, in multiples of ``factor`` × the fixed-P training's samples (a joint sample has cost
#: 0.61-1.56 fixed-P samples' work on the bar, bar_3d, the aleph and the octopus under work VERSION 2, so the
#: budget is met far before it)
CAP = 4

#: multiply-adds of the joint fit per unit of work (a unit is one factor nonzero, :mod:`defop.variational.work`, about
#: 20 ns of CPU): fitted once on the bar's and the aleph's joint trainings within 5x (fits of 1,870 and 838 samples,
#: 2.2 and 1.1 CPU s: 59 and 77 a unit, their geometric mean; benchmarks/README.md, 2026-12-02, sixth part), with the
#: fit counted as c³/3 + c² n d multiply-adds (c centres, n vertices in d dimensions). 130 before (fifth part).
FIT_FLOPS = 67.0

#: of the samples the work so far says are still needed, the share solved in the next block (the rest, a chunk at a
#: time at the end, keeps the samples solved beyond m within one chunk)
AHEAD = 0.9


def fit_work(m, n_vertices, dim, centres="auto"):
    """(k,) the work of the joint fit of m (k,) samples: (c³/3 + c² n d) / :data:`FIT_FLOPS`, c the fit's centres
    (:func:`defop.operator.fit.centre_count`, the rest poses counted as many as the samples)."""
    m = np.atleast_1d(np.asarray(m, np.int64))
    c = np.array([centre_count(centres, int(k), 2 * int(k)) for k in m], float)
    return (c**3 / 3 + c**2 * n_vertices * dim) / FIT_FLOPS


def budget_work(record, factor=mv.BUDGET, units=None):
    """The work ``factor`` fixed-P trainings cost: ``factor`` × ``record.work`` (a
    :class:`~defop.training.record.TrainingRecord` of ``dop.train``, e.g. at m = 200).

    Parameters
    ----------
    units : dict, optional
        The units the budget is spent in (:func:`defop.training.work.units`): the record's ``work_units`` must be
        equal.

    Raises
    ------
    ValueError
        ``factor`` not a positive finite number; a record without work (NaN: its ground truth was loaded from a
        cache that did not keep it, or resumed from a checkpoint: train it again with ``cache=False``) or with none;
        a record whose work is in other units than ``units`` (both named).
    """
    factor = opt.positive("factor", factor)
    spent = getattr(record, "work", None)
    if spent is None or not np.isfinite(spent) or spent <= 0:
        raise ValueError(
            f"the fixed-P training's record holds no work (work = {spent!r}): its ground truth was loaded from a "
            "cache that did not keep it, or resumed from a checkpoint; train it with cache=False"
        )
    theirs = getattr(record, "work_units", None)
    if units is not None and theirs != units:
        raise ValueError(
            f"the fixed-P training's work is in other units than the joint solves' ({theirs!r} against {units!r}): "
            "train both under the same back end (DEFOP_BACKEND) and DEFOP_REUSE, e.g. with movable_budget.reference"
        )
    return factor * float(spent)


def reference(shape, m=200, seed=0, **kw):
    """The fixed-P training a budget is counted in: ``dop.train(shape, m=m, seed=seed, **kw)`` (:func:`defop.training.
    bootstrap.train`), its record's work read from the cached ground truth, or, where the cache kept none in this
    run's units (a truth cached before work was counted, or under another back end or re-use setting: :func:`defop.
    training.work.units`), trained again without the cache.

    Returns
    -------
    op : defop.operator.core.DefOp
    record : defop.training.record.TrainingRecord
        With ``work`` finite.
    """

    op, record = train(shape, m=m, seed=seed, **kw)
    if not np.isfinite(record.work) or record.work_units != work_mod.units(shape.mesh):
        op, record = train(shape, m=m, seed=seed, **{**kw, "cache": False})
    return op, record


def stop_at(work, setup, idx, target, fit=None):
    """Where the work of a seeded sequence first reaches ``target``: (m, the work of the first m samples), or
    (None, the work of them all) when it never does.

    Parameters
    ----------
    work, setup : (k,) numpy arrays
        Per sample the work of its factorisations and its solvers' setup (:mod:`defop.training.work`).
    idx : (k, b) int numpy array
        The placements: a placement's setup counts once, at its first sample.
    target : float
    fit : (k,) numpy array, optional
        The work of fitting the first 1, 2, ..., k samples (:func:`fit_work`), added to theirs.

    Raises
    ------
    ValueError
        A sample without work (NaN).
    """
    total = _totals(work, setup, idx, fit)
    reached = np.flatnonzero(total >= target)
    if len(reached) == 0:
        return None, float(total[-1]) if len(total) else 0.0
    m = int(reached[0]) + 1
    return m, float(total[m - 1])


def _totals(work, setup, idx, fit=None):
    """(k,) the work of the first 1, 2, ..., k samples (:func:`stop_at`'s arguments), ValueError on a NaN."""
    work, setup = np.asarray(work, float), np.asarray(setup, float)
    if not (np.isfinite(work).all() and np.isfinite(setup).all()):
        raise ValueError(
            "a joint sample has no work (NaN): its solves did not run in this count (a truth cached or "
            "checkpointed without its work); solve the joint samples with counted=True, or with cache=False"
        )
    return work_mod.prefix(work, setup, work_mod.first_of(idx)) + (0.0 if fit is None else np.asarray(fit, float))


def _ahead(solved, spent, target, cap, n, dim, centres):
    """How many chunks the next block solves: 1 first, then :data:`AHEAD` of those that the work per sample so far
    and the fit's growth say the budget still needs (at least 1). A function of counted work only: the same wherever
    the same back end runs the same solves."""
    if solved == 0:
        return 1
    per = (spent - fit_work(solved, n, dim, centres)[0]) / solved  # a sample's solves and setup, on average
    grid = np.arange(solved + 1, cap + 1)
    reach = np.flatnonzero(per * grid + fit_work(grid, n, dim, centres) >= target)
    need = (grid[reach[0]] if len(reach) else cap) - solved
    return max(1, int(AHEAD * need) // batch.CHUNK)


def train_within(
    shape,
    placement,
    reference,
    factor=mv.BUDGET,
    energy="sarap",
    seed=0,
    n_q=1,
    n_jobs=None,
    cache=True,
    progress=True,
    centres="auto",
    policy="auto",
):
    """The joint operator within a budget of ``factor`` fixed-P trainings, counted in work (module docstring).

    Parameters
    ----------
    shape, placement
        As :func:`defop.training.movable.train_movable`'s.
    reference : defop.training.record.TrainingRecord
        The fixed-P training the budget is counted in (``dop.train(shape, m=200)``; its ``work``).
    factor : float
        The budget, in fixed-P trainings (default :data:`defop.training.movable.BUDGET`).
    energy, seed, n_q, n_jobs, cache, progress, centres, policy
        As :func:`~defop.training.movable.train_movable`'s; ``seed`` seeds the one sequence of joint samples.

    Returns
    -------
    op : defop.operator.movable.MovableOp
        Fitted to the first m samples of the sequence.
    record : defop.training.movable.MovableRecord
        Of those m samples; ``work`` their solves' (with setup) and draws' (:data:`defop.training.work.DRAW` each),
        ``work_units`` its units, ``budget`` the target, the factor, the fit's work (``"fit"``: ``work`` + it is what
        met the target), how many were solved to find m and whether the sequence ended first (``"capped"``:
        :data:`CAP`, warned). ``cpu_seconds`` and ``solve_cpu_seconds`` count every chunk solved (the last chunk's
        samples beyond m too).

    Raises
    ------
    ValueError
        Before any solve: a record without work, or with work in other units than this run's joint solves
        (:func:`defop.training.work.units`; both named), a bad ``factor`` (:func:`budget_work`), a bad ``centres``,
        and what :func:`~defop.training.movable.train_movable` refuses.
    """
    en.check_energy(energy)
    n_q = opt.integer("n_q", n_q, minimum=1)
    opt.seed(seed)
    opt.choice("policy", policy, ml.POLICIES)
    mv.check_placement(shape, placement)
    n, dim = shape.mesh.V.shape
    fit_work(2, n, dim, centres)  # a bad ``centres`` fails here, before any solve
    units = work_mod.units(shape.mesh)
    target = budget_work(reference, factor, units)
    cap = int(CAP * np.ceil(factor * len(reference.samples)))
    clock, rng = solves.Stopwatch(), np.random.default_rng(seed)
    got, m, spent, solve_cpu, solved = [], None, 0.0, 0.0, 0
    while m is None and solved < cap:
        k = _ahead(solved, spent, target, cap, n, dim, centres)  # chunks in this block, from the work so far
        chunks = [mv.sample_joint(shape, placement, -(-batch.CHUNK // n_q), rng, n_q) for _ in range(k)]
        idx, Q = (np.concatenate([c[i] for c in chunks]) for i in (0, 1))  # the sequence's next k chunks
        X, conv, remote, block_cpu, used, info = mv._solve_joint(
            shape, placement, idx, Q, energy, n_jobs, progress, cache, policy, counted=True
        )  # one block: the samples of one placement share its solvers (by_placement)
        clock.remote += remote
        solve_cpu += block_cpu
        budget_work(reference, factor, info.pop("work_units"))  # the joint solves' units: the reference's
        got.append((idx, Q, X, conv, info.pop("work") + work_mod.DRAW, info.pop("setup")))  # its draw too
        idx_all, work, setup = (np.concatenate([g[i] for g in got]) for i in (0, 4, 5))
        solved = len(idx_all)
        fit = fit_work(np.arange(1, solved + 1), n, dim, centres)
        m, spent = stop_at(work, setup, idx_all, target, fit)
    capped = m is None
    if capped:
        m = solved
        warnings.warn(f"the joint sequence ended ({cap} samples) before its work reached the budget", stacklevel=2)
    m = max(m, 2)  # the work of the m samples fitted, the fit's apart (MovableRecord.work: the solves')
    budget = {"target": target, "factor": float(factor), "fit": float(fit[m - 1]), "solved": solved, "capped": capped}
    idx, Q, X, conv = (np.concatenate([g[k] for g in got])[:m] for k in range(4))
    op, fit_cpu = mv.fit_joint(shape, placement, idx, Q, X, conv, energy, seed, centres)
    levels = {k: v for k, v in info.items() if k in ("fallback", "coarse_vertices")}  # per-sample rules: per block
    record = mv.MovableRecord(idx, Q, X, conv, clock.wall, clock.cpu, solve_cpu, fit_cpu, used, levels)
    record.work, record.budget, record.work_units = float(_totals(work, setup, idx_all)[m - 1]), budget, units
    return op, record
