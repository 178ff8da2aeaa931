"""The on-disk cache (defop.training.cache): keys, atomic writes, corrupt entries, a bad DEFOP_CACHE, concurrent
writers."""

from __future__ import annotations

import io
import multiprocessing
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import defop as dop
from defop import options
from defop.analysis import trajectories as tr
from defop.training import cache as cm

TRAIN = dict(energy="sarap", basis="tps", m=8, seed=4, n_jobs=1, progress=False)


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


@pytest.fixture
def folder(tmp_path, monkeypatch):
    path = tmp_path / "cache"
    monkeypatch.setenv("DEFOP_CACHE", str(path))
    return path


def _entries(folder, kind):
    return sorted(folder.glob(f"{kind}-*.npz"))


# ------------------------------------------------------------------------------------------ keys
def test_key_is_deterministic_and_sees_every_part():
    V = np.arange(6.0).reshape(3, 2)
    k = cm.key("gt", V, "sarap", {"tol": 1e-9, "mu": (1e-5,)})
    assert k == cm.key("gt", V.copy(), "sarap", {"mu": (1e-5,), "tol": 1e-9}) and len(k) == 20
    others = [
        cm.key("op", V, "sarap", {"tol": 1e-9, "mu": (1e-5,)}),
        cm.key("gt", V + 1e-15, "sarap", {"tol": 1e-9, "mu": (1e-5,)}),
        cm.key("gt", V.reshape(2, 3), "sarap", {"tol": 1e-9, "mu": (1e-5,)}),  # same bytes, other shape
        cm.key("gt", V.astype(np.float32), "sarap", {"tol": 1e-9, "mu": (1e-5,)}),
        cm.key("gt", V, "arap", {"tol": 1e-9, "mu": (1e-5,)}),
        cm.key("gt", V, "sarap", {"tol": 1e-8, "mu": (1e-5,)}),
    ]
    assert len({k, *others}) == 1 + len(others)


def test_key_includes_the_library_version_and_the_solver_salt(monkeypatch):
    k = cm.key("gt", 1)
    monkeypatch.setattr(cm, "__version__", "99.0")
    k_version = cm.key("gt", 1)
    monkeypatch.setattr(cm, "SOLVER_SALT", cm.SOLVER_SALT + 1)
    assert len({k, k_version, cm.key("gt", 1)}) == 3


def test_key_rejects_parts_it_cannot_hash_stably():
    with pytest.raises(TypeError, match="cache key part of type object"):
        cm.key(object())


def test_solver_settings_hold_everything_that_changes_a_solution(bar):
    s = cm.solver_settings(dop.variational.Solver(bar.mesh, bar.handles, "sarap"))
    assert {"energy", "tol", "max_iter", "mu_schedule", "stage_tol", "exact_switch"} <= set(s)
    assert s["tol"] == 1e-9 and s["mu_schedule"] == (1e-5, 0.0)  # S-ARAP ends on Eq. (11) itself
    for kw in ({"tol": 1e-6}, {"max_iter": 10}, {"smoothing": (1e-5, 1e-9)}):
        assert cm.solver_settings(dop.variational.Solver(bar.mesh, bar.handles, "sarap", **kw)) != s, kw


@pytest.mark.parametrize("energy", ["arap", "sarap", "isometric"])
def test_train_keys_read_the_settings_of_the_solver_train_uses(bar, energy):
    """train reads the settings from a one-triangle Solver: they must equal the real one's."""
    real = cm.solver_settings(dop.variational.Solver(bar.mesh, bar.handles, energy))
    assert dop.training.solves.solver_key(bar, energy) == real and real["energy"] == energy


def test_train_keys_in_3d_read_the_3d_solvers_settings():
    """S-ARAP's default schedule depends on the dimension: a 3D shape's key has the 3D solver's settings."""
    bar3 = dop.shapes.load("bar_3d", 300)
    real = cm.solver_settings(dop.variational.Solver(bar3.mesh, bar3.handles, "sarap"))
    assert dop.training.solves.solver_key(bar3, "sarap") == real and real["mu_schedule"] == (0.0,)


# ------------------------------------------------------------------------------ store and load
def test_store_load_round_trip_is_atomic(tmp_path):
    store = cm.Cache(tmp_path)
    X = np.random.default_rng(0).random((3, 4, 2))
    path = store.store("gt", "k", {"X": X, "converged": np.ones(3, bool)}, meta={"times": {"solve": 1.5}})
    assert path == tmp_path / "gt-k.npz" and os.listdir(tmp_path) == ["gt-k.npz"]  # no temporary file left
    arrays, meta = store.load("gt", "k", {"X": ((3, None, 2), "f"), "converged": ((3,), "b")})
    assert np.array_equal(arrays["X"], X) and meta == {"times": {"solve": 1.5}}
    assert store.load("gt", "other", {}) is None


def test_a_failed_write_leaves_the_old_entry_and_no_temporary_file(tmp_path):
    store = cm.Cache(tmp_path)
    store.store("gt", "k", {"X": np.zeros(2)})

    def broken(tmp):
        Path(tmp).write_bytes(b"PK half a file")
        raise KeyboardInterrupt  # a write killed midway

    with pytest.raises(KeyboardInterrupt):
        store.store_with("gt", "k", broken)
    assert os.listdir(tmp_path) == ["gt-k.npz"]
    assert np.array_equal(store.load("gt", "k", {"X": ((2,), "f")})[0]["X"], np.zeros(2))


def test_a_cache_that_becomes_unwritable_warns_and_keeps_the_result(bar, folder, monkeypatch):
    """DEFOP_CACHE was fine at the start and fails at the end (disk full, permissions changed)."""

    def no_space(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(options.os, "replace", no_space)  # the one atomic write (options.write_atomic)
    with pytest.warns(cm.CacheWarning, match=r"could not write the cache entry .*No space left") as rec:
        op, r = dop.train(bar, **TRAIN)
    assert r.cache == "none" and np.abs(op(r.samples) - r.X).max() < 1e-8
    written = sorted(str(w.message).split("cache/")[1][:3] for w in rec)
    assert written == ["gt-", "op-"] and list(folder.iterdir()) == []  # no entry, no temp file


def _truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _savez(path, **arrays):
    """An entry as store writes it (with its metadata), holding the arrays given."""
    np.savez(path, __meta__=np.array("{}"), **arrays)


CORRUPTIONS = {
    "truncated": (lambda p: _truncate(p), "BadZipFile"),
    "garbage": (lambda p: p.write_bytes(b"not a zip file at all"), "BadZipFile|ValueError|OSError|not a zip archive"),
    "empty": (lambda p: p.write_bytes(b""), "EOFError|BadZipFile|ValueError|not a zip archive"),
    "missing key": (lambda p: _savez(p, converged=np.ones(3, bool)), "missing array 'X'"),
    "wrong shape": (lambda p: _savez(p, X=np.zeros((3, 5, 2)), converged=np.ones(3, bool)), "shape"),
    "wrong dtype": (lambda p: _savez(p, X=np.zeros((3, 4, 2)), converged=np.ones(3)), "dtype"),
    "NaN": (lambda p: _savez(p, X=np.full((3, 4, 2), np.nan), converged=np.ones(3, bool)), "NaN or infinite"),
    "inf": (lambda p: _savez(p, X=np.full((3, 4, 2), np.inf), converged=np.ones(3, bool)), "NaN or infinite"),
    "bad meta": (
        lambda p: np.savez(p, X=np.zeros((3, 4, 2)), converged=np.ones(3, bool), __meta__=np.array("{")),
        "JSONDecodeError",
    ),
    "meta not a dict": (
        lambda p: np.savez(p, X=np.zeros((3, 4, 2)), converged=np.ones(3, bool), __meta__=np.array("[1]")),
        "not a dict",
    ),
    "missing meta": (lambda p: np.savez(p, X=np.zeros((3, 4, 2)), converged=np.ones(3, bool)), "missing its metadata"),
}


@pytest.mark.parametrize("how", list(CORRUPTIONS))
def test_a_corrupt_entry_is_removed_with_a_warning_naming_the_file(tmp_path, how):
    store = cm.Cache(tmp_path)
    path = store.store("gt", "k", {"X": np.zeros((3, 4, 2)), "converged": np.ones(3, bool)})
    corrupt, reason = CORRUPTIONS[how]
    corrupt(path)
    assert path.exists()
    with pytest.warns(cm.CacheWarning, match="corrupt cache entry") as rec:
        assert store.load("gt", "k", {"X": ((3, 4, 2), "f"), "converged": ((3,), "b")}) is None
    message = str(rec[0].message)
    assert str(path) in message and any(r in message for r in reason.split("|")), message
    assert not path.exists()


@pytest.mark.parametrize("seed", range(4))
def test_random_damage_is_detected_or_harmless(tmp_path, seed):
    """Truncations at random lengths and single flipped bytes anywhere: a load never returns other data."""
    rng = np.random.default_rng(seed)
    store = cm.Cache(tmp_path)
    X = rng.random((3, 5, 2))
    expect = {"X": ((3, 5, 2), "f"), "converged": ((3,), "b")}
    good = store.store("gt", "k", {"X": X, "converged": np.ones(3, bool)}, meta={"t": 1}).read_bytes()
    for _ in range(150):
        data = bytearray(good)
        if rng.random() < 0.5:
            data = data[: rng.integers(0, len(data))]
        else:
            data[rng.integers(len(data))] ^= 1 << int(rng.integers(8))
        store.path("gt", "k").write_bytes(bytes(data))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            got = store.load("gt", "k", expect)
        if got is None:
            assert [w.category for w in caught] == [cm.CacheWarning], [str(w.message) for w in caught]
        else:  # the byte was in a field the reader ignores (a timestamp, ...)
            assert np.array_equal(got[0]["X"], X) and got[0]["converged"].all() and got[1] == {"t": 1}


def test_load_with_removes_an_entry_its_reader_rejects(tmp_path):
    store = cm.Cache(tmp_path)
    path = store.store("op", "k", {"W": np.zeros(2)})

    def reject(p):
        raise cm.CorruptEntry("does not match the shape")

    with pytest.warns(cm.CacheWarning, match="does not match the shape") as rec:
        assert store.load_with("op", "k", reject) is None
    assert str(path) in str(rec[0].message) and not path.exists()


def test_an_entry_path_that_is_a_directory_is_ignored_with_a_warning_and_kept(tmp_path):
    c = cm.Cache(tmp_path)
    c.path("gt", "k").mkdir()
    (c.path("gt", "k") / "user-file").write_text("not ours")
    with pytest.warns(cm.CacheWarning, match="not a regular file"):
        assert c.load("gt", "k", {"a": ((None,), "f")}) is None
    with pytest.warns(cm.CacheWarning, match="could not write"):
        assert c.store("gt", "k", {"a": np.zeros(2)}) is None  # the result is still the caller's
    assert (c.path("gt", "k") / "user-file").read_text() == "not ours"


def test_a_corrupt_entry_replaced_meanwhile_by_another_process_is_kept(tmp_path):
    store = cm.Cache(tmp_path)
    path = store.store("gt", "k", {"X": np.zeros(2)})
    _truncate(path)

    def reader(p):
        with open(p, "rb") as fh:  # this process opened the truncated entry ...
            store.store("gt", "k", {"X": np.ones(2)})  # ... another one renamed a whole entry into place
            return dict(np.load(fh))

    with pytest.warns(cm.CacheWarning, match="corrupt cache entry"):
        assert store.load_with("gt", "k", reader) is None
    assert np.array_equal(store.load("gt", "k", {"X": ((2,), "f")})[0]["X"], np.ones(2))


# -------------------------------------------------------------------- corrupt entries in train
@pytest.mark.parametrize("kind", ["gt", "op"])
def test_train_recomputes_a_truncated_entry(bar, folder, kind):
    a, ra = dop.train(bar, **TRAIN)
    (entry,) = _entries(folder, kind)
    _truncate(entry)
    if kind == "gt":  # else the cached operator is served (without X when its ground truth is corrupt)
        _entries(folder, "op")[0].unlink()
    with pytest.warns(cm.CacheWarning, match="corrupt cache entry") as rec:
        b, rb = dop.train(bar, **TRAIN)
    assert str(entry) in str(rec[0].message)
    assert rb.cache == ("ground truth" if kind == "op" else "none")
    assert np.allclose(a(ra.samples), b(rb.samples), atol=1e-12) and np.allclose(ra.X, rb.X, atol=1e-12)
    with warnings.catch_warnings():  # the entry was rewritten whole
        warnings.simplefilter("error", cm.CacheWarning)
        c, rc = dop.train(bar, **TRAIN)
    assert rc.cache == "operator" and np.array_equal(rc.X, rb.X)


def test_train_recomputes_an_operator_with_nan_coefficients(bar, folder):
    a, ra = dop.train(bar, **TRAIN)
    (entry,) = _entries(folder, "op")
    op = dop.DefOp.load(entry)
    op.W[0, 0] = np.nan
    op.save(entry)
    with pytest.warns(cm.CacheWarning, match="NaN") as rec:
        b, rb = dop.train(bar, **TRAIN)
    assert str(entry) in str(rec[0].message) and rb.cache == "ground truth"
    assert np.isfinite(b.W).all() and np.allclose(a(ra.samples), b(rb.samples), atol=1e-12)


def test_train_cache_misses_when_a_solver_setting_the_version_or_the_salt_changes(bar, folder, monkeypatch):
    dop.train(bar, **TRAIN)
    assert dop.train(bar, **TRAIN)[1].cache == "operator"

    class LooserSolver(dop.variational.Solver):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            self.stage_tol = 1e-6

    with monkeypatch.context() as mp:
        mp.setattr(dop.training.solves, "Solver", LooserSolver)
        assert dop.train(bar, **TRAIN)[1].cache == "none"
    with monkeypatch.context() as mp:
        mp.setattr(cm, "SOLVER_SALT", cm.SOLVER_SALT + 1)
        assert dop.train(bar, **TRAIN)[1].cache == "none"
    with monkeypatch.context() as mp:
        mp.setattr(cm, "__version__", "0.0.0+other")
        assert dop.train(bar, **TRAIN)[1].cache == "none"
    assert dop.train(bar, **TRAIN)[1].cache == "operator"  # the original entries are still there


def test_sample_ground_truth_round_trip_and_recompute(bar, folder):
    Q = dop.training.sampling.sample_shape(bar, 3, 7)
    X, c = dop.training.bootstrap.sample_ground_truth(bar, Q, "arap", n_jobs=1, progress=False)
    (entry,) = _entries(folder, "gt")
    X2, c2 = dop.training.bootstrap.sample_ground_truth(bar, Q, "arap", n_jobs=1, progress=False)
    assert np.array_equal(X, X2) and np.array_equal(c, c2)
    _savez(entry, X=X[:2], converged=c[:2])  # an entry for other samples under this key
    with pytest.warns(cm.CacheWarning, match="shape"):
        X3, _ = dop.training.bootstrap.sample_ground_truth(bar, Q, "arap", n_jobs=1, progress=False)
    assert np.allclose(X, X3, atol=1e-12)


# ------------------------------------------------------------- corrupt entries in trajectories
def test_trajectories_recompute_a_truncated_entry(bar, folder):
    g = tr.handle_grid(bar.P_moving[0], 0.05, 2)
    a = tr.ground_truth_trajectories(bar, g, "arap", n_jobs=1)
    (entry,) = _entries(folder, "traj")
    _truncate(entry)
    with pytest.warns(cm.CacheWarning, match="corrupt cache entry") as rec:
        b = tr.ground_truth_trajectories(bar, g, "arap", n_jobs=1)
    assert str(entry) in str(rec[0].message) and np.allclose(a.X, b.X, atol=1e-12)


def test_trajectory_keys_see_the_solver_settings_and_the_salt(bar, monkeypatch):
    g = tr.handle_grid(bar.P_moving[0], 0.05, 2)
    solver = {}  # the solver's options (the defaults)
    k = tr._cache_key(bar, g, "sarap", "global", 0, None, solver, {})
    tighter = {"smoothing": (1e-5, 1e-9)}
    assert tr._cache_key(bar, g, "sarap", "global", 0, None, tighter, {}) != k
    assert tr._cache_key(bar, g, "sarap", "global", 0, None, solver, {"tol": 1e-6}) != k
    monkeypatch.setattr(cm, "SOLVER_SALT", cm.SOLVER_SALT + 1)
    assert tr._cache_key(bar, g, "sarap", "global", 0, None, solver, {}) != k


# ------------------------------------------------------------------------------ bad DEFOP_CACHE
def _no_solves(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("a solve ran before DEFOP_CACHE was checked")

    monkeypatch.setattr(dop.variational.Solver, "solve", fail)  # the primitive every driver calls


def _bad_cache_values(tmp_path):
    afile = tmp_path / "a-file"
    afile.write_text("x")
    return {
        "a file": (afile, "is not a directory"),
        "impossible to create": (afile / "sub", "cannot create"),
        "read-only (/proc/1)": (Path("/proc/1"), "cannot write"),
    }


@pytest.mark.parametrize("case", ["a file", "impossible to create", "read-only (/proc/1)"])
def test_a_bad_defop_cache_fails_before_any_work(bar, tmp_path, monkeypatch, case):
    path, what = _bad_cache_values(tmp_path)[case]
    monkeypatch.setenv("DEFOP_CACHE", str(path))
    _no_solves(monkeypatch)
    calls = [
        lambda: dop.train(bar, **TRAIN),
        lambda: dop.training.held_out(bar, "sarap", 4, 9, n_jobs=1, progress=False),
        lambda: dop.training.bootstrap.sample_ground_truth(bar, bar.P_moving[None], "sarap", n_jobs=1, progress=False),
        lambda: tr.ground_truth_trajectories(bar, tr.handle_grid(bar.P_moving[0], 0.05, 2), n_jobs=1),
    ]
    for call in calls:
        with pytest.raises(ValueError, match="DEFOP_CACHE") as exc:
            call()
        assert str(path) in str(exc.value) and what in str(exc.value)


def test_a_read_only_defop_cache_is_named():
    """A directory without write permission, checked by an unprivileged process (root may write anywhere)."""
    base = Path(tempfile.mkdtemp(prefix="defop-ro-"))
    try:
        base.chmod(0o755)
        ro = base / "ro"
        ro.mkdir(mode=0o555)
        ro.chmod(0o555)
        kw = dict(user=65534, group=65534, extra_groups=[]) if os.geteuid() == 0 else {}
        env = {**os.environ, "DEFOP_CACHE": str(ro)}
        code = "import defop; defop.config.cache_dir()"
        try:
            r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, **kw)
        except PermissionError as exc:  # root, with the interpreter where nobody may run it (e.g. under /root)
            pytest.skip(f"cannot run Python as an unprivileged user here ({exc}); /proc/1 covers read-only")
    finally:
        shutil.rmtree(base)
    last = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
    assert r.returncode != 0 and last.startswith("ValueError: DEFOP_CACHE="), r.stderr
    assert str(ro) in last and "cannot write" in last, last


def test_defop_cache_off_disables_the_cache(bar, tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE", "off")
    monkeypatch.setenv("HOME", str(tmp_path))  # the default location must stay untouched too
    assert cm.open_cache() is None
    a = dop.train(bar, **TRAIN)[1]
    b = dop.train(bar, **TRAIN)[1]
    assert a.cache == b.cache == "none" and list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- two processes
def _slow_savez(started, may_finish):
    """np.savez that writes half the bytes, signals, waits until allowed, then writes the rest."""
    real = np.savez

    def savez(file, *args, **kw):
        buf = io.BytesIO()
        real(buf, *args, **kw)
        data = buf.getvalue()
        fh = open(file, "wb") if isinstance(file, (str, os.PathLike)) else file
        fh.write(data[: len(data) // 2])
        fh.flush()
        started.set()
        may_finish.wait(120)
        fh.write(data[len(data) // 2 :])
        fh.flush()
        if fh is not file:
            fh.close()

    return savez


def _train_child(cache, out, started=None, may_finish=None):
    os.environ["DEFOP_CACHE"] = cache
    os.environ["DEFOP_N_JOBS"] = "1"
    if started is not None:
        np.savez = _slow_savez(started, may_finish)
    import defop

    warnings.simplefilter("error", defop.training.cache.CacheWarning)  # seeing a half-written entry is a failure
    shape = defop.scene.shapes.load("bar", n_vertices=200)
    op, rec = defop.training.bootstrap.train(shape, **TRAIN)
    np.save(out, np.stack([op(rec.samples), rec.X]))


def test_two_processes_training_the_same_operator_both_get_it(bar, tmp_path, monkeypatch):
    """Process A writes each entry slowly, held mid-write while process B starts training the same operator; B
    waits on the entry's lock (Cache.lock) or reads A's whole entry, never the half-written one. (It used to wait
    for B to finish first, which the per-entry lock makes B wait out: 2 x 120 s of timeouts.)"""
    ctx = multiprocessing.get_context("spawn")
    started, go_on = ctx.Event(), ctx.Event()
    cache = str(tmp_path / "cache")
    a = ctx.Process(target=_train_child, args=(cache, tmp_path / "a.npy", started, go_on))
    a.start()
    try:
        assert started.wait(120), "process A never started writing"
        assert [p.name for p in Path(cache).glob(".gt-*")]  # A's half-written ground truth is on disk
        b = ctx.Process(target=_train_child, args=(cache, tmp_path / "b.npy"))
        b.start()
        go_on.set()  # A finishes its entries while B trains
        b.join(300)
        assert b.exitcode == 0, "process B failed while A was writing"
        a.join(300)
        assert a.exitcode == 0
    finally:
        go_on.set()
        a.join(10)
        if a.is_alive():
            a.kill()
    ra, rb = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")  # [op(Q_k), X_k] of each process
    assert np.allclose(ra, rb, atol=1e-12) and np.abs(ra[0] - ra[1]).max() < 1e-8  # same, and Prop. 1 holds
    assert len(_entries(Path(cache), "gt")) == len(_entries(Path(cache), "op")) == 1
    assert not list(Path(cache).glob(".*"))  # no temporary file left behind
    monkeypatch.setenv("DEFOP_CACHE", cache)
    with warnings.catch_warnings():  # the entries are whole: loaded without a CacheWarning
        warnings.simplefilter("error", cm.CacheWarning)
        op, rec = dop.train(bar, **TRAIN)
    assert rec.cache == "operator" and np.allclose(op(rec.samples), ra[0], atol=1e-12)
    assert np.array_equal(rec.X, ra[1])


def test_a_writer_killed_midway_leaves_no_entry(bar, tmp_path, monkeypatch):
    ctx = multiprocessing.get_context("spawn")
    started, never = ctx.Event(), ctx.Event()
    cache = tmp_path / "cache"
    a = ctx.Process(target=_train_child, args=(str(cache), tmp_path / "a.npy", started, never))
    a.start()
    try:
        assert started.wait(120)
    finally:
        a.kill()
        a.join(30)
    assert _entries(cache, "gt") == [] and _entries(cache, "op") == []
    (litter,) = cache.glob(".gt-*.tmp.npz")  # the killed writer's half-written temporary file
    monkeypatch.setenv("DEFOP_CACHE", str(cache))
    cm.open_cache()
    assert litter.exists()  # it could still be a live writer's
    old = time.time() - cm.STALE_SECONDS - 1
    os.utime(litter, (old, old))
    cm.open_cache()
    assert not litter.exists()  # an hour old: a killed writer's, removed
    with warnings.catch_warnings():
        warnings.simplefilter("error", cm.CacheWarning)
        op, rec = dop.train(bar, **TRAIN)
    assert rec.cache == "none" and len(_entries(cache, "op")) == 1


def test_the_main_jobs_journal_lists_the_entries_stored_and_read(tmp_path, monkeypatch):
    from defop.training import cache_files

    log = tmp_path / "journal"
    monkeypatch.setenv("DEFOP_CACHE_LOG", str(log))
    (tmp_path / "c").mkdir()
    cache = cm.Cache(tmp_path / "c")
    cache.store("gt", "a" * 20, {"X": np.zeros(2)})
    assert cache.load("gt", "b" * 20, {"X": ((2,), "f")}) is None  # a miss is not a read
    assert cache.load("gt", "a" * 20, {"X": ((2,), "f")}) is not None
    name = "gt-" + "a" * 20 + ".npz"
    assert cache_files.journal_entries(log.read_text()) == ([name], [name])
