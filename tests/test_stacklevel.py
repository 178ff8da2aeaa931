"""Every public path that warns names the user's line (issue 35): the warning's ``filename`` is this file, however
deep in defop the warning is raised (one policy, :func:`defop.options.user_stacklevel`)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import defop as dop
from defop import options as opt
from defop.analysis import branches as ab
from defop.analysis import trajectories as tr
from defop.operator.branched import Branch, BranchedOperator
from defop.operator.defop import ExtrapolationWarning
from defop.training import adaptive, batch, bootstrap, solves
from defop.training import cache as cm
from defop.variational.solver import NotConvergedWarning


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture(scope="module")
def op(bar):
    return dop.train(bar, "arap", "linear", m=4, seed=1, n_jobs=1, progress=False, cache=False)[0]


@pytest.fixture(scope="module")
def bop(bar, op):
    """Two branches (the bar's linear operator twice, sides +1 and -1): far from the samples, none exists."""
    z = np.zeros(op.handle_basis.size)
    return BranchedOperator(
        [Branch(0, op, z, z + 1, 1), Branch(1, op, z, z + 1, -1)], np.zeros_like(bar.mesh.V), np.zeros(1 + op.P.size)
    )


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _points_here(category, call):
    """Run ``call`` and check it warned ``category`` at least once, every time at a line of this file."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        call()
    hits = [w for w in caught if issubclass(w.category, category)]
    assert hits, f"no {category.__name__}: {[str(w.message) for w in caught]}"
    assert {w.filename for w in hits} == {__file__}, [(w.filename, w.lineno, str(w.message)[:60]) for w in hits]


def _far(op, k=None):
    Q = op.P - 100.0 * (1 + np.arange(op.P.size).reshape(op.P.shape))  # beyond every sample (and λ² < 0)
    return Q if k is None else np.repeat(Q[None], k, axis=0)


# ---------------------------------------------------------------------------------------- ExtrapolationWarning
@pytest.mark.parametrize("k", [None, 1, 5])
def test_defop_far_from_the_samples(op, k):
    _points_here(ExtrapolationWarning, lambda: op(_far(op, k)))


@pytest.mark.parametrize("compressed", [False, True])
def test_defop_fast_paths_far_from_the_samples(op, tmp_path, compressed):
    op.save(tmp_path / "op.npz")
    c = dop.DefOp.load(tmp_path / "op.npz")
    if compressed:
        c.compress(rank=2)  # the factored fast paths (evaluate_fast, the interactive one, does not warn by design)
    _points_here(ExtrapolationWarning, lambda: c(_far(c)))
    _points_here(ExtrapolationWarning, lambda: c(_far(c, 3)))
    _points_here(ExtrapolationWarning, lambda: c.evaluate_batch(_far(c, 3)))
    near = c.P + 0.05 * (_far(c, 3) - c.P)  # 5 bar lengths: far, within the vectorised path's overflow guard
    _points_here(ExtrapolationWarning, lambda: c.evaluate_batch(near))


@pytest.mark.parametrize(
    "call",
    [
        lambda b, Q: b(Q),
        lambda b, Q: b(Q[None]),
        lambda b, Q: b.choose(Q),
        lambda b, Q: b(Q, branch=1),
        lambda b, Q: b.session().step(Q),
        lambda b, Q: b.session()(Q),
        lambda b, Q: b.session().run(Q[None]),
    ],
    ids=["global", "global batch", "choose", "branch", "session step", "session call", "session run"],
)
def test_branched_operator_far_from_every_branch(bop, op, call):
    _points_here(ExtrapolationWarning, lambda: call(bop, _far(op)))


# ----------------------------------------------------------------------------------------- NotConvergedWarning
def test_solver_solve_and_solve_best_and_dop_solve(bar):
    T = bar.targets(bar.P_moving + [[0.0, 0.3]])
    s = dop.variational.Solver(bar.mesh, bar.handles, "sarap", max_iter=1)
    _points_here(NotConvergedWarning, lambda: s.solve(T))
    _points_here(NotConvergedWarning, lambda: s.solve_best(T))
    _points_here(NotConvergedWarning, lambda: dop.solve(bar.mesh, bar.handles, T, max_iter=1))


def _unconverged(monkeypatch):
    real = solves.solve_chunk

    def solve(problem, jobs):
        return [r._replace(converged=False) for r in real(problem, jobs)]

    monkeypatch.setattr(solves, "solve_chunk", solve)


def test_train_with_unconverged_samples(bar, monkeypatch):
    _unconverged(monkeypatch)
    kw = dict(energy="arap", basis="linear", m=4, seed=1, n_jobs=1, progress=False, cache=False)
    _points_here(NotConvergedWarning, lambda: dop.train(bar, **kw))


def test_train_adaptive_with_unconverged_samples(bar, monkeypatch):
    _unconverged(monkeypatch)
    kw = dict(energy="arap", basis="linear", m=6, batch=2, pool=4, n_jobs=1, progress=False, cache=False)
    _points_here(NotConvergedWarning, lambda: adaptive.train_adaptive(bar, **kw))


def test_trajectories_with_unconverged_solves(bar, cache):
    g = tr.handle_grid(bar.P_moving[0], 0.2, 2)
    _points_here(
        RuntimeWarning, lambda: tr.ground_truth_trajectories(bar, g, "sarap", n_jobs=1, solver_kw={"max_iter": 1})
    )


def test_branch_comparison_with_unconverged_continuation(bar, op, bop, monkeypatch):
    Qs = bar.P_moving[None] + np.linspace(0, 0.05, 4)[:, None, None] * np.array([0.0, 1.0])
    X = op(Qs)

    def path(shape, Qs, energy="sarap", X0=None):
        return X, np.zeros(len(Qs)), np.array([True, False, True, True])

    monkeypatch.setattr(ab, "solver_path", path)
    _points_here(UserWarning, lambda: ab.compare(bar, bop, op, Qs, "arap", window=1))


# ----------------------------------------------------------------------------------------------- CacheWarning
def test_a_corrupt_entry_met_by_train(bar, cache):
    kw = dict(energy="arap", basis="linear", m=4, seed=1, n_jobs=1, progress=False)
    dop.train(bar, **kw)
    for entry in cache.glob("*.npz"):
        entry.write_bytes(b"garbage")
    _points_here(cm.CacheWarning, lambda: dop.train(bar, **kw))


def test_an_entry_of_another_problem_met_by_sample_ground_truth(bar, cache):
    Q = dop.training.sampling.sample_shape(bar, 2, 5)
    bootstrap.sample_ground_truth(bar, Q, "arap", n_jobs=1, progress=False)
    (entry,) = cache.glob("gt-*.npz")
    entry.rename(entry.with_name("gt-" + "0" * 20 + ".npz"))
    store = cm.open_cache()
    _points_here(cm.CacheWarning, lambda: store.load("gt", "0" * 20, {}))


def test_a_checkpoint_of_another_problem(bar, tmp_path, monkeypatch):
    monkeypatch.setattr(batch, "CHUNK", 1)
    store = cm.Cache(tmp_path)
    Q = dop.training.sampling.sample_shape(bar, 2, 5)
    cp = batch.Checkpoints(store)
    bootstrap.solve_samples(bar, Q, "arap", n_jobs=1, progress=False, checkpoint=cp)
    a, b = (store.path("chunk", k) for k in cp.keys)
    b.write_bytes(a.read_bytes())
    _points_here(
        cm.CacheWarning,
        lambda: bootstrap.solve_samples(bar, Q, "arap", n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store)),
    )


def test_an_unwritable_entry(tmp_path):
    store = cm.Cache(tmp_path)
    store.path("gt", "k").mkdir()
    _points_here(cm.CacheWarning, lambda: store.store("gt", "k", {"X": np.zeros(2)}))
    _points_here(cm.CacheWarning, lambda: store.load("gt", "k", {}))


# ------------------------------------------------------------------------------------------------ the others
def test_more_workers_than_cores(bar, cache):
    kw = dict(energy="arap", basis="linear", m=4, seed=1, progress=False)
    dop.train(bar, n_jobs=1, **kw)  # cached: the second call only checks its options
    _points_here(RuntimeWarning, lambda: dop.train(bar, n_jobs=10_000, **kw))
    _points_here(RuntimeWarning, lambda: opt.n_jobs(10_000))


def test_an_image_of_two_regions():
    img = np.zeros((40, 60))
    img[5:35, 5:30] = 1.0
    img[5:15, 40:50] = 1.0  # a second, smaller blob: dropped with a warning
    _points_here(UserWarning, lambda: dop.shapes.from_image(img, n_vertices=150))


def test_the_policy_counts_defop_frames_only():
    def here():
        return opt.user_stacklevel()

    assert here() == 1  # a function outside defop that warns: its own line
