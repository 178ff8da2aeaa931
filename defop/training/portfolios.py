"""The training policies on the sample engine (:mod:`defop.training.solves`): the start portfolio and the multilevel
fine stage.

:func:`portfolio` is the one start portfolio of training: the first dn + 1 samples from the rest pose and a linear
fit to them; every other sample from the rest pose and that fit's prediction; then ``rounds - 1`` rounds from a
smooth fit's prediction, the current solution verified as the incumbent, the lowest verified minimum kept. The full
policy runs it on the shape's mesh; the multilevel policy runs the same code on a coarse mesh, keeping every end
point, and :func:`refine` runs the fine stage (the per-sample rule :func:`defop.training.multilevel.refine_one`
decides from them).
"""

from __future__ import annotations

import functools
import os
import time
import warnings

import numpy as np

from ..operator import handle_bases as hb
from ..operator.fit import fit
from ..variational.solver import NotConvergedWarning
from . import batch, solves, work

__all__ = ["portfolio", "refine"]


def _smooth(m, n, d):
    """The smooth predictor of the later rounds (not an interpolant, which would reproduce a bad local minimum)."""
    return "quadratic" if m + 1 >= hb.basis_size("quadratic", n, d=d) else "linear"


def portfolio(shape, samples, energy, n_jobs=None, progress=True, rounds=2, checkpoint=None, keep="best", meta=None):
    """The start portfolio of every sample (see the module docstring).

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
        The mesh it runs on (the fine shape, or a coarse level's).
    samples : (m, n, d) numpy array
    energy : str
    n_jobs, progress
        As :func:`defop.training.solves.solve`.
    rounds : int
    checkpoint : defop.training.batch.Checkpoints, optional
    keep : str
        ``"best"`` or ``"all"``: keep every end point of every round (no checkpoints).
    meta : dict, optional
        The fitted predictors' metadata.

    Returns
    -------
    X : (m, n_vertices, d) numpy array
    converged : (m,) bool numpy array
    times : dict
        CPU seconds of the stages ``bootstrap`` (its solves and the linear fit) and ``solve``.
    wall : dict
        Their wall seconds.
    runs : list or None
        Per sample every end point ``(X, energy, converged)`` (``keep="all"``).
    """
    mesh, m, n, d = shape.mesh, len(samples), shape.n_moving, shape.mesh.V.shape[1]
    meta = {"shape": shape.name, "energy": energy} if meta is None else meta
    run = functools.partial(solves.solve, shape, energy=energy, n_jobs=n_jobs, progress=progress, keep=keep)
    ck = checkpoint if keep == "best" else None
    nb = min(m, hb.basis_size("linear", n, d=d))  # dn + 1: the linear bootstrap fit
    clock = solves.Stopwatch()
    first = clock.add(run(samples[:nb], desc="bootstrap solves", checkpoint=ck))
    lin = fit(mesh, shape.handles, shape.moving, samples[:nb], first.X, "linear", "hat", meta=meta)
    times, wall = {"bootstrap": clock.cpu}, {"bootstrap": clock.wall}
    clock = solves.Stopwatch()
    X, conv, runs = first.X, first.converged, first.runs
    if m > nb:
        starts = batch.warm_starts(lin, samples[nb:], mesh, energy)
        more = clock.add(run(samples[nb:], starts=starts, desc="sample solves", checkpoint=ck))
        X, conv = np.concatenate([X, more.X]), np.concatenate([conv, more.converged])
        runs = None if runs is None else runs + more.runs
    for r in range(2, rounds + 1):
        inter = fit(mesh, shape.handles, shape.moving, samples, X, _smooth(m, n, d), "hat", meta=meta)
        starts = batch.warm_starts(inter, samples, mesh, energy)
        desc = f"re-solves, round {r} of {rounds}"
        again = clock.add(run(samples, starts=starts, incumbents=X, rest=False, desc=desc, checkpoint=ck))
        X, conv = again.X, again.converged
        runs = None if runs is None else [a + b for a, b in zip(runs, again.runs)]
    times["solve"], wall["solve"] = clock.cpu, clock.wall
    return X, conv, times, wall, runs


def _refine_chunk(decide, lv, problem, jobs):
    """``decide`` (:func:`defop.training.multilevel.refine_one`) per (targets, candidates, handles) job, with its CPU
    seconds; a job with handles (h,) runs on ``lv.at(handles)`` with the fine solver of those handles
    (:meth:`defop.training.solves.Problem.solver_for`: built in its CPU seconds unless kept from an earlier job)."""
    out, pid = [], os.getpid()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for T, c, h in jobs:
            t0, w0 = time.process_time(), work.reading()
            level, solver = lv if h is None else lv.at(h), problem.solver_for(h)
            res = decide(level, solver, T, c)
            out.append((*res, time.process_time() - t0, pid, work.reading() - w0, work.setup_of(solver)))
    return out


_FIELDS = ("X", "converged", "rule", "iterations", "minima", "coarse_energy")


def _refine_cache(checkpoint, key_of, n, d, rules):
    """``map_checkpointed``'s chunk callable for :func:`refine`: every field of a chunk's results in one entry."""
    if checkpoint is None or key_of is None:
        return None

    def expect(k):
        kinds = ("f", "b", "i", "i", "i", "f")
        return {f: ((k, n, d) if f == "X" else (k,), kind) for f, kind in zip(_FIELDS, kinds)}

    def chunk(a, b, compute):
        fresh = []

        def arrays():
            fresh.extend(compute())
            cols = list(zip(*fresh))
            return {
                "X": np.array(cols[0]),
                "converged": np.array(cols[1], bool),
                "rule": np.array([rules.index(r) + 1 if r else 0 for r in cols[2]]),
                "iterations": np.array(cols[3], int),
                "minima": np.array(cols[4], int),
                "coarse_energy": np.nan_to_num(np.array(cols[5], float), nan=-1.0),
            }

        got = checkpoint.load_or_compute(key_of(a, b), expect(b - a), arrays)
        names = ["" if r == 0 else rules[r - 1] for r in got["rule"]]
        cols = (got["X"], got["converged"], names, got["iterations"], got["minima"], got["coarse_energy"])
        # refined now: its CPU seconds and work; loaded: none, its work not counted (NaN)
        clocks = [r[6:] for r in fresh] or [(0.0, 0, np.nan, np.nan)] * (b - a)
        return [(*row, *clock) for row, clock in zip(zip(*cols), clocks)]

    return chunk


def refine(
    lv,
    samples,
    energy,
    candidates,
    decide,
    rules,
    n_jobs=None,
    progress=True,
    checkpoint=None,
    key_of=None,
    handles=None,
):
    """The fine stage of every sample, in parallel and checkpointed.

    Parameters
    ----------
    lv : defop.training.multilevel.CoarseLevel
    samples : (m, n, d) numpy array
    energy : str
    candidates : list of m lists
        Every coarse end point per sample (:func:`portfolio` with ``keep="all"`` on ``lv.coarse``).
    decide : callable
        The per-sample rule, ``decide(lv, solver, T, candidates) -> (X, converged, rule, iterations, minima,
        coarse_energy)`` (:func:`defop.training.multilevel.refine_one`).
    rules : tuple of str
        Its safeguard rules (:data:`defop.training.multilevel.RULES`), for the checkpoints.
    checkpoint : defop.training.batch.Checkpoints, optional
    key_of : callable, optional
        ``key_of(a, b)``: the checkpoint key of samples a..b (everything that determines them).
    handles : (m, h) int numpy array, optional
        Per sample the fine handle vertices (movable handles: :meth:`defop.training.multilevel.CoarseLevel.at`,
        ``candidates`` solved on the coarse mesh with the handles at their coarse vertices); default ``lv``'s handles.

    Returns
    -------
    X : (m, n, d) numpy array
    converged : (m,) bool numpy array
    info : dict
        Per sample: ``rule`` (str, "" when the safeguard did not fire), ``iterations`` (the single fine run's),
        ``minima`` (distinct verified coarse minima), ``coarse_energy``, ``cpu`` (CPU seconds of the sample's fine
        stage in the process that ran it; 0 for a sample loaded from a checkpoint), ``work`` and ``setup`` (its
        factorisations' work and its fine solver's setup, :mod:`defop.training.work`; NaN where loaded).
    cpu : float
        CPU seconds of the runs in other processes (:class:`defop.training.solves.Stopwatch` adds this one's).
    """
    fine = lv.fine
    problem = solves.Problem(fine.mesh, fine.handles, energy)
    if handles is None:
        problem.solver_for(None)  # built once here, shipped to the workers
        jobs = [(fine.targets(q), c, None) for q, c in zip(samples, candidates)]
    else:
        handles = solves.check_handles(fine, handles, len(samples))  # solvers per handle set, where they run
        jobs = [(solves.targets_at(fine, h, q), c, h) for q, c, h in zip(samples, candidates, handles)]
    n, d = fine.mesh.V.shape
    chunk = _refine_cache(checkpoint, key_of, n, d, tuple(rules))
    res = batch.map_checkpointed(
        functools.partial(_refine_chunk, decide, lv, problem), jobs, n_jobs, progress, "fine runs", chunk
    )
    cols = list(zip(*res))
    info = {
        "rule": [str(r) for r in cols[2]],
        "iterations": [int(i) for i in cols[3]],
        "minima": [int(k) for k in cols[4]],
        "coarse_energy": [float(e) for e in cols[5]],
        "cpu": [float(t) for t in cols[6]],
        "work": [float(w) for w in cols[8]],
        "setup": [float(w) for w in cols[9]],
    }
    at = [fine.handles] * len(jobs) if handles is None else handles
    work.count(info["work"], info["setup"], [work.solver_key(fine.mesh, h) for h in at])
    remote = float(sum(t for t, pid in zip(cols[6], cols[7]) if pid not in (0, os.getpid())))
    return np.array(cols[0]), np.array(cols[1], bool), info, remote
