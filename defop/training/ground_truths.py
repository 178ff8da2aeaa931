"""The ground truth of a training (:func:`defop.training.bootstrap.train`): its cache key, loaded from the cache or
solved by the training policy and stored.

While one process solves a ground truth, another that needs the same one waits for it
(:meth:`defop.training.cache.Cache.lock`) and loads it.
"""

from __future__ import annotations

from . import batch, portfolios, solves, work
from . import cache as cache_mod
from . import multilevel as ml

__all__ = ["cached", "ground_truth", "load", "solve", "train_key"]


def load(store, key, m, n_vertices, d=2):
    """(X, converged, meta) of a cached ground truth, or None."""
    entry = None if store is None else store.load("gt", key, solves.gt_expect(m, n_vertices, d))
    return None if entry is None else (entry[0]["X"], entry[0]["converged"], entry[1])


def _multilevel(lv, samples, energy, n_jobs, progress, rounds, ck, key_parts):
    """The multilevel policy (:mod:`defop.training.multilevel`): (X, converged, CPU times, wall times, info).

    The coarse stage is the full policy's start portfolio on the coarse mesh, every end point kept
    (:func:`defop.training.portfolios.portfolio`)."""
    clock = solves.Stopwatch()
    _, _, _, _, cands = portfolios.portfolio(lv.coarse, samples, energy, n_jobs, progress, rounds, keep="all")
    times, wall = {"coarse": clock.cpu}, {"coarse": clock.wall}
    clock = solves.Stopwatch()
    key_of = None if ck is None else lambda a, b: cache_mod.key("ml-fine", *key_parts, a, b)
    X, conv, info, remote = portfolios.refine(
        lv, samples, energy, cands, ml.refine_one, ml.RULES, n_jobs, progress, ck, key_of
    )
    clock.remote += remote
    times["fine"], wall["fine"] = clock.cpu, clock.wall
    info["coarse_vertices"] = lv.coarse.mesh.n_vertices
    return X, conv, times, wall, info


def train_key(shape, energy, samples, rounds, used, lv):
    """The ground truth's cache key: mesh, handles, energy, the solver's settings, the samples, ``rounds`` and the
    policy that runs (with the multilevel constants and the coarse mesh)."""
    mesh, settings = shape.mesh, solves.solver_key(shape, energy)
    policy = {"policy": used, "round 2": "verified incumbent"}
    coarse = []
    if lv is not None:
        policy.update(ml.constants())
        policy["coarse portfolio"] = "full"  # the coarse stage runs the full policy's portfolio (an incumbent verified)
        coarse = [lv.coarse.mesh.V, lv.coarse.mesh.F, lv.coarse.handles]
    return cache_mod.key(
        "gt-train", mesh.V, mesh.F, shape.handles, shape.moving, energy, settings, samples, rounds, policy, *coarse
    )


def ground_truth(shape, samples, energy, n_jobs, progress, rounds, store, gt_key, lv, meta):
    """The training's ground truth, loaded or solved by the policy and cached: (X, converged, CPU times, wall times,
    multilevel info, cache state, work (:mod:`defop.training.work`; kept with the truth and its units, NaN for a
    truth cached without it or in other units))."""
    gt = cached(store, gt_key, shape, len(samples))
    if gt is not None:
        return gt
    with batch.hold(store, "gt", gt_key):  # another process solving these samples: wait for it, then load them
        gt = cached(store, gt_key, shape, len(samples))
        if gt is not None:
            return gt
        return solve(shape, samples, energy, n_jobs, progress, rounds, store, gt_key, lv, meta)


def cached(store, gt_key, shape, m):
    """:func:`ground_truth`'s result from the cache (with how long its solves took when they ran), or None."""
    gt = load(store, gt_key, m, shape.mesh.n_vertices, shape.mesh.dim)
    if gt is None:
        return None
    meta = gt[2]
    times, wall, done = dict(meta.get("times", {})), dict(meta.get("wall", {})), work.recorded(meta, shape.mesh)
    return gt[0], gt[1], times, wall, meta.get("multilevel"), "ground truth", done


def solve(shape, samples, energy, n_jobs, progress, rounds, store, gt_key, lv, meta):
    """:func:`ground_truth`'s solves by the policy, cached with their CPU and wall seconds and their work."""
    ck = None if store is None else batch.Checkpoints(store)  # resume an interrupted run where it stopped
    total = len(samples) * (rounds + (lv is not None))  # every round solves each sample; multilevel: one fine run
    stages = batch.Stages(total, progress) if progress else False  # one display, one ETA, over every stage
    try:
        with work.tally() as tally:
            info = None
            if lv is None:
                X, conv, times, wall, _ = portfolios.portfolio(
                    shape, samples, energy, n_jobs, stages, rounds, ck, meta=meta
                )
            else:
                X, conv, times, wall, info = _multilevel(lv, samples, energy, n_jobs, stages, rounds, ck, [gt_key])
    finally:
        if stages:
            stages.close()
    if store is not None:
        meta = {
            "times": times,
            "wall": wall,
            "multilevel": info,
            "work": tally.total,
            "work_units": work.units(shape.mesh),
        }
        store.store("gt", gt_key, {"X": X, "converged": conv}, meta=meta)
        ck.discard()  # the whole ground truth is cached
    return X, conv, times, wall, info, "none", tally.total
