"""Hostile cache entries (issue 35): an entry of another problem under this problem's key (a copied or renamed file,
a shared cache directory) is never used, whatever its kind; an entry without a digest is stale; a damaged digest is
a corrupt entry."""

from __future__ import annotations

import io
import json
import shutil
import warnings
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import defop as dop
from defop.analysis import trajectories as tr
from defop.training import adaptive, batch, bootstrap, solves
from defop.training import branches as tb
from defop.training import cache as cm

EXPECT = {"X": ((3, 4, 2), "f"), "converged": ((3,), "b")}


@pytest.fixture(scope="module")
def bar():
    return dop.shapes.load("bar", n_vertices=200)


def _arrays(value=0.0):
    return {"X": np.full((3, 4, 2), value), "converged": np.ones(3, bool)}


def _problem(bar, handles, moving, name="bar"):
    """The bar's mesh with other handles (one moving handle, so the bar's sampling region fits)."""
    return dop.scene.shapes.Shape(name, bar.mesh, np.array(handles), np.array(moving, bool), bar.regions)


# ------------------------------------------------------------------------------------------- the cache layer
@pytest.mark.parametrize("via", ["store", "store_with"])
def test_an_entry_of_another_key_is_removed_with_a_warning_naming_both_digests(tmp_path, via):
    store = cm.Cache(tmp_path)
    if via == "store":
        src = store.store("gt", "a" * 20, _arrays(1.0))
    else:
        src = store.store_with("gt", "a" * 20, lambda tmp: np.savez(tmp, __meta__=np.array("{}"), **_arrays(1.0)))
    dst = store.path("gt", "b" * 20)
    shutil.copy(src, dst)  # a copied (or renamed) file: valid arrays of the right shapes, another problem's
    with pytest.warns(cm.CacheWarning, match="another problem") as rec:
        assert store.load("gt", "b" * 20, EXPECT) is None
    message = str(rec[0].message)
    assert str(dst) in message and "gt-" + "a" * 20 in message and "gt-" + "b" * 20 in message
    assert not dst.exists() and src.exists()  # only the misplaced copy goes
    store.store("gt", "b" * 20, _arrays(2.0))  # recomputed and stored: used from now on, without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert store.load("gt", "b" * 20, EXPECT)[0]["X"][0, 0, 0] == 2.0
        assert store.load("gt", "a" * 20, EXPECT)[0]["X"][0, 0, 0] == 1.0


def test_the_kind_is_part_of_the_digest(tmp_path):
    store = cm.Cache(tmp_path)
    shutil.copy(store.store("gt", "k", _arrays()), store.path("chunk", "k"))
    with pytest.warns(cm.CacheWarning, match="'gt-k', this problem's is 'chunk-k'"):
        assert store.load("chunk", "k", EXPECT) is None


def test_an_entry_without_a_digest_is_stale_and_recomputed_silently(tmp_path):
    """An entry written by an older defop (no digest): not an error, not used, overwritten by the new result."""
    store = cm.Cache(tmp_path)
    path = store.path("gt", "k")
    np.savez(path, __meta__=np.array("{}"), **_arrays(1.0))  # the layout of FORMAT 1, without the stamp
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert store.load("gt", "k", EXPECT) is None
        got = batch.load_or_compute(store, "gt", "k", EXPECT, lambda: _arrays(2.0))
        assert got["X"][0, 0, 0] == 2.0
        assert store.load("gt", "k", EXPECT)[0]["X"][0, 0, 0] == 2.0  # rewritten with its digest


def _tamper(path, how):
    data = bytearray(path.read_bytes())
    n = len(cm.STAMP) + len("gt-k " + cm.VERSION_TAG)
    if how == "other digest":
        data[-1] ^= 0x01
    elif how == "truncated stamp":
        data = data[:-3]
    elif how == "no stamp, bytes left":  # the end record says: no comment; the stamp's bytes follow it anyway
        data[-n - 2 : -n] = b"\x00\x00"
    elif how == "not a digest":
        data[-n:] = b"x" * n
    elif how == "stamp cut off":  # the end record still declares the comment
        data = data[:-n]
    path.write_bytes(bytes(data))


@pytest.mark.parametrize(
    "how, reason",
    [
        ("other digest", "another problem"),
        ("truncated stamp", "corrupt cache entry"),
        ("no stamp, bytes left", "corrupt cache entry"),
        ("not a digest", "not a defop cache digest"),
        ("stamp cut off", "corrupt cache entry"),
    ],
)
def test_a_damaged_digest_is_never_taken_for_a_good_one(tmp_path, how, reason):
    store = cm.Cache(tmp_path)
    path = store.store("gt", "k", _arrays(1.0))
    _tamper(path, how)
    with pytest.warns(cm.CacheWarning, match=reason) as rec:
        assert store.load("gt", "k", EXPECT) is None
    assert str(path) in str(rec[0].message) and not path.exists()


def test_an_operator_entry_carries_its_digest_and_still_loads_as_an_operator_file(bar, tmp_path):
    op, _ = dop.train(bar, "arap", "linear", m=4, seed=1, n_jobs=1, progress=False, cache=False)
    store = cm.Cache(tmp_path)
    path = store.store_with("op", "k", op.save)
    assert path.read_bytes().endswith(cm.STAMP + b"op-k " + cm.VERSION_TAG.encode())
    assert np.array_equal(dop.DefOp.load(path).W, op.W)  # the stamp is the archive's comment: readers ignore it
    shutil.copy(path, store.path("op", "j"))
    with pytest.warns(cm.CacheWarning, match="another problem"):
        assert store.load_with("op", "j", dop.DefOp.load) is None


# ---------------------------------------------------------------------- every kind, through its real caller
def _misplace(folder_a, folder_b, kind):
    """Put problem A's entry of ``kind`` under the name of problem B's (B's own entry is replaced)."""
    (a,) = sorted(folder_a.glob(f"{kind}-*.npz"))
    (b,) = sorted(folder_b.glob(f"{kind}-*.npz"))
    shutil.copy(a, b)
    return b


def test_ground_truth_of_other_handles_is_not_used(bar, tmp_path, monkeypatch):
    """The bar with its 4 handles and with 2 of them: the same mesh, samples and energy, other solutions."""
    sub = _problem(bar, bar.handles[:2], bar.moving[:2], "bar-2-handles")
    Q = dop.training.sampling.sample_shape(bar, 3, 7)
    kw = dict(energy="arap", n_jobs=1, progress=False)
    for problem, name in ((bar, "a"), (sub, "b")):
        monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / name))
        bootstrap.sample_ground_truth(problem, Q, **kw)
    entry = _misplace(tmp_path / "a", tmp_path / "b", "gt")
    ref, _ = bootstrap.sample_ground_truth(sub, Q, cache=False, **kw)
    with pytest.warns(cm.CacheWarning, match="another problem") as rec:
        X, conv = bootstrap.sample_ground_truth(sub, Q, **kw)
    assert str(entry) in str(rec[0].message)
    assert np.array_equal(X, ref) and conv.all()
    other, _ = bootstrap.sample_ground_truth(bar, Q, cache=False, **kw)
    assert np.abs(other - ref).max() > 1e-3  # what was there would have been a wrong answer


def test_a_resumed_training_does_not_fit_to_checkpoints_of_another_problem(bar, tmp_path, monkeypatch):
    """The case of issue 35: the checkpoints of an interrupted training of the bar with 4 handles, under the keys
    of the same training with 2 handles (the same mesh, sample count and chunks)."""
    monkeypatch.setattr(batch, "CHUNK", 2)
    sub = _problem(bar, bar.handles[:2], bar.moving[:2], "bar-2-handles")
    Q = dop.training.sampling.sample_shape(bar, 5, 3)
    keys = {}
    for problem, name in ((bar, "a"), (sub, "b")):
        cp = batch.Checkpoints(cm.Cache(tmp_path))
        bootstrap.solve_samples(problem, Q, "arap", n_jobs=1, progress=False, checkpoint=cp)
        keys[name] = cp.keys
    assert len(keys["a"]) == 3 and not set(keys["a"]) & set(keys["b"])
    store = cm.Cache(tmp_path)
    for ka, kb in zip(keys["a"], keys["b"]):
        shutil.copy(store.path("chunk", ka), store.path("chunk", kb))
    ref, _ = bootstrap.solve_samples(sub, Q, "arap", n_jobs=1, progress=False)
    with pytest.warns(cm.CacheWarning, match="another problem") as rec:
        X, _ = bootstrap.solve_samples(sub, Q, "arap", n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store))
    assert len([w for w in rec if "another problem" in str(w.message)]) == 3  # every chunk
    assert np.array_equal(X, ref)


def test_an_operator_of_another_energy_is_not_used(bar, tmp_path, monkeypatch):
    """ARAP's and S-ARAP's operators of the bar: the same mesh, handles, Ψ, Φ and m, which the reader checks."""
    kw = dict(basis="tps", m=8, seed=4, n_jobs=1, progress=False)
    for energy, name in (("arap", "a"), ("sarap", "b")):
        monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / name))
        dop.train(bar, energy, **kw)
    _misplace(tmp_path / "a", tmp_path / "b", "op")
    with pytest.warns(cm.CacheWarning, match="another problem"):
        op, rec = dop.train(bar, "sarap", **kw)
    ref, _ = dop.train(bar, "sarap", cache=False, **kw)
    assert rec.cache == "ground truth" and np.allclose(op.W, ref.W, atol=1e-10)


def test_trajectories_of_another_energy_are_not_used(bar, tmp_path, monkeypatch):
    g = tr.handle_grid(bar.P_moving[0], 0.05, 2)
    for energy, name in (("arap", "a"), ("sarap", "b")):
        monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / name))
        tr.ground_truth_trajectories(bar, g, energy, n_jobs=1)
    _misplace(tmp_path / "a", tmp_path / "b", "traj")
    with pytest.warns(cm.CacheWarning, match="another problem"):
        got = tr.ground_truth_trajectories(bar, g, "sarap", n_jobs=1)
    ref = tr.ground_truth_trajectories(bar, g, "sarap", n_jobs=1, cache=False)
    assert np.array_equal(got.X, ref.X)


def test_branch_minima_of_another_energy_are_not_used(bar, tmp_path, monkeypatch):
    Q = bar.P_moving[None] + np.array([[[0.0, 0.05]], [[0.0, -0.05]]])
    for energy, name in (("arap", "a"), ("sarap", "b")):
        monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / name))
        tb.discover(bar, Q, energy=energy)
    _misplace(tmp_path / "a", tmp_path / "b", "branch-minima")
    with pytest.warns(cm.CacheWarning, match="another problem"):
        got = tb.discover(bar, Q, energy="sarap")
    ref = tb.discover(bar, Q, energy="sarap", cache=False)
    assert not got.seconds["cached"] and np.array_equal(got.X, ref.X)


# ------------------------------------------------------------------------- random mutations of the problem
def _fake_solves(monkeypatch):
    """Replace the solves by a cheap map that depends on the whole problem; returns the list of solve counts."""
    calls = []

    def solve(problem, jobs):
        calls.append(len(jobs))
        out = []
        for T, *_ in jobs:
            X = problem.mesh.V + {"arap": 0.0, "sarap": 1.0, "isometric": 2.0}[problem.energy]
            X[problem.handles] = T
            X += 1e-3 * len(problem.handles)
            out.append(solves.Item(X, 0.0, True))
        return out

    monkeypatch.setattr(solves, "solve_chunk", solve)
    return calls


MUTATIONS = ("swap fixed", "drop fixed", "other fixed", "other moving", "energy", "samples", "sample order")


def _mutate(bar, Q, energy, how, data):
    """(handles, moving, energy, Q) of a problem that differs from the bar's in ``how``."""
    handles, moving = list(bar.handles), list(bar.moving)
    fixed = [i for i in range(len(handles)) if not moving[i]]
    if len(fixed) < (2 if how == "swap fixed" else 1) and how in MUTATIONS[:4]:
        how = "energy"  # no fixed handle left to change
    if how == "swap fixed":
        i, j = data.draw(st.lists(st.sampled_from(fixed), min_size=2, max_size=2, unique=True))
        handles[i], handles[j] = handles[j], handles[i]
    elif how == "drop fixed":
        drop = data.draw(st.lists(st.sampled_from(fixed), min_size=1, max_size=len(fixed), unique=True))
        keep = [i for i in range(len(handles)) if i not in drop]
        handles, moving = [handles[i] for i in keep], [moving[i] for i in keep]
    elif how == "other fixed":
        i = data.draw(st.sampled_from(fixed))
        handles[i] = data.draw(st.integers(0, bar.mesh.n_vertices - 1).filter(lambda v: v not in handles))
    elif how == "other moving":
        i = data.draw(st.sampled_from(fixed))
        moving = [i == j for j in range(len(moving))]
    elif how == "energy":
        energy = data.draw(st.sampled_from([e for e in ("arap", "sarap", "isometric") if e != energy]))
    elif how == "samples":
        k = data.draw(st.integers(0, len(Q) - 1))
        Q = Q.copy()
        Q[k, 0, data.draw(st.integers(0, 1))] += data.draw(st.sampled_from([1e-12, 1e-6, 0.01]))
    else:
        Q = Q[::-1].copy()
    return handles, moving, energy, Q


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), hows=st.lists(st.sampled_from(MUTATIONS), min_size=1, max_size=3, unique=True))
def test_no_mutation_of_the_problem_reuses_another_problems_entries(bar, tmp_path_factory, monkeypatch, data, hows):
    """Handles swapped, dropped or replaced, another moving handle, energy or samples: with every entry of the bar's
    problem (its ground truth and checkpoints) placed under the mutated problem's names, the mutated problem
    solves every sample itself and gets its own answers."""
    monkeypatch.setattr(batch, "CHUNK", 2)
    calls = _fake_solves(monkeypatch)
    Q, mutated, energy_b, Q_b = _mutated(bar, data, hows)
    energy = "arap"
    folder = tmp_path_factory.mktemp("cache")
    store = cm.Cache(folder)
    names = {}
    for problem, e, q, name in ((bar, energy, Q, "a"), (mutated, energy_b, Q_b, "b")):
        cp = batch.Checkpoints(store)
        X, _ = bootstrap.solve_samples(problem, q, e, n_jobs=1, progress=False, checkpoint=cp)
        names[name] = (cp.keys, X)
    (keys_a, _), (keys_b, ref) = names["a"], names["b"]
    if keys_a == keys_b:  # the mutations cancelled (a swap undone): the same problem, its entries are its own
        return
    for ka, kb in zip(keys_a, keys_b):
        if ka != kb:  # the chunks whose inputs differ; an equal chunk (same samples, same problem) is shared
            shutil.copy(store.path("chunk", ka), store.path("chunk", kb))
    differ = sum(ka != kb for ka, kb in zip(keys_a, keys_b))
    calls.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        X, _ = bootstrap.solve_samples(
            mutated, Q_b, energy_b, n_jobs=1, progress=False, checkpoint=batch.Checkpoints(store)
        )
    assert np.array_equal(X, ref)
    foreign = [w for w in caught if issubclass(w.category, cm.CacheWarning) and "another problem" in str(w.message)]
    assert len(foreign) == differ
    assert sum(calls) == sum(min(2, 5 - 2 * i) for i, (a, b) in enumerate(zip(keys_a, keys_b)) if a != b)


def _mutated(bar, data, hows):
    """The bar's problem (handles, moving, energy "arap", 5 samples) and a mutation of it: (Q, problem, energy, Q)."""
    Q, energy = dop.training.sampling.sample_shape(bar, 5, 11), "arap"
    handles, moving, energy_b, Q_b = bar.handles, bar.moving, energy, Q
    for how in hows:
        handles, moving, energy_b, Q_b = _mutate(_problem(bar, handles, moving), Q_b, energy_b, how, data)
    return Q, _problem(bar, handles, moving, "mutated"), energy_b, Q_b


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), hows=st.lists(st.sampled_from(MUTATIONS), min_size=1, max_size=3, unique=True))
def test_no_mutation_of_the_problem_reuses_another_problems_ground_truth(
    bar, tmp_path_factory, monkeypatch, data, hows
):
    """As above for the whole ground truth of :func:`sample_ground_truth` (``gt``), the bar's entry renamed to the
    mutated problem's name in a shared cache directory."""
    monkeypatch.setattr(batch, "CHUNK", 2)
    calls = _fake_solves(monkeypatch)
    Q, mutated, energy_b, Q_b = _mutated(bar, data, hows)
    folders = [tmp_path_factory.mktemp(name) for name in ("a", "b", "shared")]
    got = []
    for folder, (problem, e, q) in zip(folders, ((bar, "arap", Q), (mutated, energy_b, Q_b))):
        monkeypatch.setenv("DEFOP_CACHE", str(folder))
        got.append(bootstrap.sample_ground_truth(problem, q, e, n_jobs=1, progress=False)[0])
    (a,), (b,) = (list(f.glob("gt-*.npz")) for f in folders[:2])
    if a.name == b.name:  # the mutations cancelled: the same problem
        return
    shutil.copy(a, folders[2] / b.name)
    monkeypatch.setenv("DEFOP_CACHE", str(folders[2]))
    calls.clear()
    with pytest.warns(cm.CacheWarning, match="another problem"):
        X, _ = bootstrap.sample_ground_truth(mutated, Q_b, energy_b, n_jobs=1, progress=False)
    assert np.array_equal(X, got[1]) and sum(calls) == 5  # every sample solved again


def test_a_resumed_adaptive_training_uses_no_entry_of_another_problem(bar, tmp_path, monkeypatch):
    """Every entry an adaptive training of the bar under ARAP wrote (its initial ground truth and operator, each
    batch's ground truth), renamed to the entry the S-ARAP training wrote at the same step: the S-ARAP training run
    again solves every sample itself and returns what it returned the first time."""
    calls = _fake_solves(monkeypatch)
    written, real = [], cm.Cache.store_with

    def recording(self, kind, key, write):
        written.append((kind, key))
        return real(self, kind, key, write)

    monkeypatch.setattr(cm.Cache, "store_with", recording)
    kw = dict(basis="linear", m=10, batch=2, seed=2, n_jobs=1, progress=False)
    runs = {}
    for energy, name in (("arap", "a"), ("sarap", "b")):
        monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / name))
        written.clear()
        op, rec = adaptive.train_adaptive(bar, energy, **kw)
        runs[name] = (list(written), op, rec, sum(calls))
        calls.clear()
    assert [k for k, _ in runs["a"][0]] == [k for k, _ in runs["b"][0]] and len(runs["a"][0]) >= 3
    for (kind, a), (_, b) in zip(runs["a"][0], runs["b"][0]):
        shutil.copy(cm.Cache(tmp_path / "a").path(kind, a), cm.Cache(tmp_path / "b").path(kind, b))
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "b"))
    with pytest.warns(cm.CacheWarning, match="another problem"):
        op, rec = adaptive.train_adaptive(bar, "sarap", **kw)
    _, ref_op, ref, solved = runs["b"]
    assert sum(calls) == solved  # nothing of the ARAP training was used
    assert np.array_equal(rec.samples, ref.samples) and np.array_equal(rec.X, ref.X) and np.array_equal(op.W, ref_op.W)


# ------------------------------------------------------------------------------- operator files (io.py)
@pytest.fixture(scope="module")
def branched_file(bar, tmp_path_factory):
    """A two-branch operator file (the bar's linear operator twice, sides +1 and -1) and its members."""
    from defop.operator.branched import Branch, BranchedOperator

    op, _ = dop.train(bar, "arap", "linear", m=4, seed=1, n_jobs=1, progress=False, cache=False)
    z = np.zeros(op.handle_basis.size)
    bop = BranchedOperator(
        [Branch(0, op, z, z + 1, 1), Branch(1, op, z, z + 1, -1)], np.zeros_like(bar.mesh.V), np.zeros(1 + op.P.size)
    )
    path = tmp_path_factory.mktemp("branched") / "two.npz"
    bop.save(path)
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    with np.load(path) as f:
        header = json.loads(str(f["header"]))
    return path, members, header


def _with_header(path, members, header):
    buf = io.BytesIO()
    np.save(buf, np.array(json.dumps(header)))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, raw in {**members, "header.npy": buf.getvalue()}.items():
            zf.writestr(name, raw)
    return path


BAD_INTEGERS = [1.5, -0.5, True, False, "²", "1", None, [1], {"v": 1}, 1e300, float("nan")]


@pytest.mark.parametrize("value", BAD_INTEGERS + [2, 0, -3])
def test_a_branch_side_that_is_not_plus_or_minus_one_is_refused(branched_file, tmp_path, value):
    """``side: 1.5`` loaded as +1 (``int()`` ran before the check); now every non-integer or other integer is refused,
    naming the file and the field."""
    from defop.operator.branched import BranchedOperator

    path, members, header = branched_file
    bad = json.loads(json.dumps(header))
    bad["branches"][1]["side"] = value
    target = _with_header(tmp_path / "side.npz", members, bad)
    with pytest.raises(ValueError, match=r"header's branches\[1\]\.side must be") as info:
        BranchedOperator.load(target)
    assert str(target) in str(info.value)


@pytest.mark.parametrize("value", [1.0, -1.0])
def test_an_integral_float_side_loads(branched_file, tmp_path, value):
    from defop.operator.branched import BranchedOperator

    path, members, header = branched_file
    header = json.loads(json.dumps(header))
    header["branches"][1]["side"] = value
    got = BranchedOperator.load(_with_header(tmp_path / "side.npz", members, header))
    assert got.branches[1].side == int(value) and type(got.branches[1].side) is int


@pytest.mark.parametrize("field", ["label", "dim", "format_version"])
@pytest.mark.parametrize("value", [0.5, True, "²", None])
def test_other_integer_header_fields_are_checked_before_int(branched_file, tmp_path, field, value):
    from defop.operator.branched import BranchedOperator

    path, members, header = branched_file
    header = json.loads(json.dumps(header))
    if field == "label":
        header["branches"][0]["label"] = False if value is True else value  # False == 0: once accepted
    else:
        header[field] = value
    target = _with_header(tmp_path / "field.npz", members, header)
    with pytest.raises(ValueError, match=f"header's (branches\\[0\\]\\.)?{field} must be an integer|label 0") as info:
        BranchedOperator.load(target)
    assert str(target) in str(info.value)


def test_a_directory_is_called_a_directory(bar, tmp_path):
    from defop.operator.branched import BranchedOperator

    for load in (dop.DefOp.load, BranchedOperator.load):
        with pytest.raises(ValueError, match="is a directory, not an operator file") as info:
            load(tmp_path)
        assert str(tmp_path) in str(info.value)


@pytest.mark.parametrize("value", [["0", "0", "0"], [True, False, False], "000", None, [[0], [0, 0]]])
def test_a_threshold_that_is_not_numbers_is_refused(branched_file, tmp_path, value):
    """Strings and booleans were cast to floats ("0" -> 0.0) before."""
    from defop.operator.branched import BranchedOperator

    path, members, header = branched_file
    header = json.loads(json.dumps(header))
    header["threshold"] = value
    target = _with_header(tmp_path / "t.npz", members, header)
    with pytest.raises(ValueError, match="threshold") as info:
        BranchedOperator.load(target)
    assert str(target) in str(info.value)
