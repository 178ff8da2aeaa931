"""The cache shared by processes (one computes an entry, the others wait and read it), the version in an entry's
stamp, and ``python -m defop cache [--prune [--dry-run]]`` (defop.training.cache_admin). Fast: no solves."""

from __future__ import annotations

import multiprocessing
import os
import time

import numpy as np
import pytest

from defop.__main__ import main
from defop.training import batch, cache_admin
from defop.training import cache as cm

EXPECT = {"X": ((3,), "f")}


def _compute_slowly(folder, log, value):
    """load_or_compute of one entry whose computation takes 0.5 s and leaves a line in ``log``."""
    store = cm.Cache(folder)

    def compute():
        with open(log, "a") as fh:
            fh.write(f"{os.getpid()}\n")
        time.sleep(0.5)
        return {"X": np.full(3, value)}

    return float(batch.load_or_compute(store, "gt", "a" * 20, EXPECT, compute)["X"][0])


def test_two_processes_missing_the_same_entry_compute_it_once(tmp_path):
    log = tmp_path / "computed.txt"
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(2) as pool:
        got = pool.starmap(_compute_slowly, [(tmp_path, log, 1.0), (tmp_path, log, 2.0)])
    assert len(log.read_text().split()) == 1  # the other waited for the lock and read the stored entry
    assert got[0] == got[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["computed.txt", "gt-" + "a" * 20 + ".npz"]  # no lock left


def test_the_lock_is_released_when_its_holder_raises(tmp_path):
    store = cm.Cache(tmp_path)
    with pytest.raises(KeyboardInterrupt), store.lock("gt", "k"):
        raise KeyboardInterrupt
    with store.lock("gt", "k"):  # not held: taken at once
        assert store.lock_path("gt", "k").exists()
    assert not store.lock_path("gt", "k").exists()


def test_stored_entries_are_journalled_for_the_main_job(tmp_path, monkeypatch):
    monkeypatch.setenv("DEFOP_CACHE_LOG", str(tmp_path / "journal"))
    store = cm.Cache(tmp_path / "c")
    (tmp_path / "c").mkdir()
    store.store("gt", "b" * 20, {"X": np.zeros(3)})
    assert (tmp_path / "journal").read_text() == "gt-" + "b" * 20 + ".npz\n"


def test_the_stamp_names_the_versions(tmp_path):
    path = cm.Cache(tmp_path).store("gt", "k", {"X": np.zeros(3)})
    assert cm.read_stamp(path) == ("gt-k", cm.VERSION_TAG)
    assert cm.SOLVER_SALT == int(cm.VERSION_TAG.rsplit("solver=", 1)[1])


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A cache holding one file of every status (``held``: a lock held by this process)."""
    store = cm.Cache(tmp_path)
    store.store("gt", "a" * 20, {"X": np.zeros(3)})  # current
    monkeypatch.setattr(cm, "VERSION_TAG", "version=0.0.1;format=1;solver=1")
    store.store("op", "b" * 20, {"X": np.zeros(3)})  # other version
    monkeypatch.undo()
    np.savez(store.path("gt", "c" * 20), X=np.zeros(3))  # no digest
    store.path("gt", "d" * 20).write_bytes(store.path("gt", "a" * 20).read_bytes())  # misnamed
    store.path("traj", "e" * 20).write_bytes(b"PK not a zip")  # damaged
    untagged = _restamp(store.path("gt", "a" * 20).read_bytes(), b"chunk-" + b"f" * 20)
    store.path("chunk", "f" * 20).write_bytes(untagged)  # untagged: a digest and no versions
    old = tmp_path / ".gt-x.npz.abc.tmp.npz"
    old.write_bytes(b"x")
    os.utime(old, (time.time() - 2 * cm.STALE_SECONDS,) * 2)  # stale temporary
    (tmp_path / ".gt-y.npz.abc.tmp.npz").write_bytes(b"x")  # in use (a writer now)
    (tmp_path / ".cold-abc").mkdir()  # a killed lesson's own cache
    (tmp_path / ".cold-abc" / "gt-x.npz").write_bytes(b"x")
    os.utime(tmp_path / ".cold-abc", (time.time() - 2 * cm.STALE_SECONDS,) * 2)
    store.lock_path("gt", "1" * 20).write_bytes(b"")  # free lock
    (tmp_path / "notes.txt").write_text("mine")  # foreign
    return tmp_path


def _restamp(data, digest):
    """An entry's bytes with its archive comment replaced by ``STAMP + digest`` (no version tag)."""
    at = data.rfind(b"PK\x05\x06")
    comment = cm.STAMP + digest
    return data[: at + 20] + len(comment).to_bytes(2, "little") + comment


STATUS = {
    "gt-" + "a" * 20 + ".npz": "current",
    "op-" + "b" * 20 + ".npz": "other version",
    "gt-" + "c" * 20 + ".npz": "no digest",
    "gt-" + "d" * 20 + ".npz": "misnamed",
    "traj-" + "e" * 20 + ".npz": "damaged",
    "chunk-" + "f" * 20 + ".npz": "untagged",
    ".gt-x.npz.abc.tmp.npz": "stale temporary",
    ".cold-abc": "stale temporary",
    ".gt-y.npz.abc.tmp.npz": "in use",
    ".gt-" + "1" * 20 + ".lock": "free lock",
    "notes.txt": "foreign",
}


def test_every_file_gets_its_status(folder):
    assert {e.path.name: e.status for e in cache_admin.scan(folder)} == STATUS


def test_prune_removes_what_no_version_reads_and_dry_run_nothing(folder):
    doomed = {n for n, s in STATUS.items() if s in cache_admin.PRUNED}
    assert {e.path.name for e in cache_admin.prune(folder, dry_run=True)} == doomed
    assert {p.name for p in folder.iterdir()} == set(STATUS)
    assert {e.path.name for e in cache_admin.prune(folder)} == doomed
    assert {p.name for p in folder.iterdir()} == set(STATUS) - doomed
    cache_admin.prune(folder, untagged=True)
    assert {p.name for p in folder.iterdir()} == {n for n, s in STATUS.items() if s in ("current", "in use", "foreign")}
    assert cm.Cache(folder).load("gt", "a" * 20, EXPECT) is not None  # the current entry still reads


def test_a_held_lock_is_in_use_and_kept(tmp_path):
    store = cm.Cache(tmp_path)
    with store.lock("gt", "k"):
        assert [e.status for e in cache_admin.scan(tmp_path)] == ["in use"]
        assert cache_admin.prune(tmp_path) == []
        assert store.lock_path("gt", "k").exists()


def test_the_command_line(folder, monkeypatch, capsys):
    monkeypatch.setenv("DEFOP_CACHE", str(folder))
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert "11 files" in out and "other version" in out and "gt " in out
    assert main(["cache", "--prune", "--dry-run"]) == 0
    assert "would remove 7 files" in capsys.readouterr().out and len(list(folder.iterdir())) == 11
    assert main(["cache", "--prune"]) == 0
    assert "removed 7 files" in capsys.readouterr().out and len(list(folder.iterdir())) == 4
