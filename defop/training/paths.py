"""The sample engine's paths: solves in sequence, each warm-started from the previous solution.

A continuation (:func:`continuation`, :func:`sweep`, :func:`sweeps`: a path of samples, like a user's drag) always
steps on; a decision-dependent path (:func:`walk`, :func:`walks`: a generator that yields ``(targets, X0)`` and
receives ``(X, energy, converged)``, e.g. a flood fill over a branch's domain or a bisection towards its fold)
chooses its next step from the last result. Independent paths run in parallel through
:func:`defop.training.batch.parallel_map`; each measures its own CPU seconds where it ran (the engine's timing rule,
:mod:`defop.training.solves`).
"""

from __future__ import annotations

import functools
import os
import time
import warnings

import numpy as np

from ..variational import energies as en
from ..variational.solver import NotConvergedWarning
from . import batch
from .solves import Item, Problem, check_samples, collect

__all__ = ["continuation", "sweep", "sweeps", "walk", "walks"]


def continuation(solver, targets, start, bar=None, solve_start="local", solve_kw=None):
    """Solves along ``targets``, each warm-started from the previous solution (the first from ``start``), the
    solver's NotConvergedWarning silenced as in every engine batch: a list of :class:`Item`.

    The one continuation of the library: :func:`sweep` runs it on a shape's samples, branch discovery
    (:func:`defop.training.branches.sweep`) on a solver's targets inside its parallel map.
    """
    out, X, pid = [], start, os.getpid()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        for T in targets:
            t0 = time.process_time()
            r = solver.solve(T, X0=X, start=solve_start, **dict(solve_kw or {}))
            X = np.asarray(r.X)
            out.append(Item(X, float(r.energy), bool(r.converged), time.process_time() - t0, pid))
            if bar:
                bar.update(1)
    return out


def sweep(shape, samples, energy="sarap", start=None, progress=False, desc="sweep", solver_kw=None, solve_kw=None):
    """A continuation sweep: the samples solved in the order given, each warm-started from the previous solution.

    Every solve is one local path (:meth:`defop.variational.solver.Solver.solve` with ``start="local"``: the solver
    moves the handles from the previous solution's positions to the sample's, through flip-free continuation
    stages where a barrier energy needs them, and escapes saddles), like a user dragging the handles; no other
    start is tried, so the result depends on the path.

    Parameters
    ----------
    shape : defop.scene.shapes.Shape
    samples : (m, n, d) numpy array
        The path's configurations of the moving handles, in order.
    energy : str
    start : (n_vertices, d) numpy array, optional
        The first solve's start (default the rest pose).
    progress : bool or callable
        A progress bar (:func:`defop.training.batch.progress`).
    desc : str
    solver_kw, solve_kw : dict, optional
        Passed to ``Solver(...)`` and ``Solver.solve(...)`` (``tol``, ``max_iter``, ``max_stages``).

    Returns
    -------
    Solves
        In the order of ``samples``. The sweep runs in this process (each solve needs the previous one).
    """
    en.check_energy(energy)
    samples = check_samples(shape, samples)
    problem = Problem(shape.mesh, shape.handles, energy, solver_kw=dict(solver_kw or {}), solve_kw=dict(solve_kw or {}))
    targets = [shape.targets(q) for q in samples]
    w0 = time.perf_counter()
    bar = batch.progress(len(targets), desc, progress)
    try:
        items = continuation(problem.solver_for(None), targets, start, bar, solve_kw=problem.solve_kw)
    finally:
        if bar:
            bar.close()
    return collect(items, time.perf_counter() - w0)


def sweep_paths(solver, items):
    """:func:`sweeps`' worker: one :func:`continuation` per item ``(targets, start)``, each a list of :class:`Item`."""
    return [continuation(solver, targets, start) for targets, start in items]


def sweeps(solver, paths, n_jobs=None, progress=False, desc="continuation sweeps"):
    """Several continuation paths at once, in parallel (one path per item): a list of :class:`Solves`.

    Parameters
    ----------
    solver : defop.variational.solver.Solver
        Built on the mesh and handles the targets are for (picklable: the workers get a copy).
    paths : sequence of (targets, start)
        Per path: the handles' targets in order ((k, h, d) or a list of (h, d) arrays) and the first solve's start
        ((n_vertices, d), or None for the rest pose).
    n_jobs, progress, desc
        As :func:`defop.training.batch.parallel_map`; the result does not depend on ``n_jobs``.
    """
    w0 = time.perf_counter()
    runs = batch.parallel_map(functools.partial(sweep_paths, solver), list(paths), n_jobs, progress, desc)
    wall = time.perf_counter() - w0
    return [collect(items, wall) for items in runs]


def walk(solver, path, solve_kw=None):
    """Run one decision path: ``path`` (a generator) yields ``(targets, X0)``, one local solve warm-started from X0,
    and receives its ``(X, energy, converged)``, until it returns. The engine's policy for paths whose next step
    depends on the last result (a flood fill over a branch's domain, a bisection towards its fold); a continuation
    (:func:`continuation`) is the path that always steps on.

    Returns
    -------
    value, cpu : object, float
        What the path returns, and the CPU seconds of the walk (``time.process_time`` where it ran).
    """
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        try:
            T, X0 = next(path)
            while True:
                r = solver.solve(T, X0=X0, start="local", **dict(solve_kw or {}))
                T, X0 = path.send((np.asarray(r.X), float(r.energy), bool(r.converged)))
        except StopIteration as stop:
            return stop.value, time.process_time() - t0


def walk_paths(solver, path, chunk):
    """:func:`walks`' worker: :func:`walk` of ``path(item)`` for every item of the chunk."""
    return [walk(solver, path(item)) for item in chunk]


def walks(solver, path, items, n_jobs=None, progress=False, desc="paths"):
    """:func:`walk` of ``path(item)`` for every item, in parallel (independent paths; the result does not depend on
    ``n_jobs``).

    Returns
    -------
    values : list
        Each path's return value, in the order of ``items``.
    cpu : float
        CPU seconds summed over the paths (each measured where it ran).
    """
    res = batch.parallel_map(functools.partial(walk_paths, solver, path), list(items), n_jobs, progress, desc)
    return [v for v, _ in res], float(sum(c for _, c in res))
