from __future__ import annotations

from pathlib import Path

import pytest

import defop as dop


def test_fast_mode_and_pick(monkeypatch):
    monkeypatch.setenv("DEFOP_FAST", "1")
    assert dop.config.fast_mode() and dop.config.pick(100, 10) == 10
    monkeypatch.setenv("DEFOP_FAST", "0")
    assert not dop.config.fast_mode() and dop.config.pick(100, 10) == 100


def test_cache_dir(monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "c"))
    assert dop.config.cache_dir() == tmp_path / "c"
    monkeypatch.setenv("DEFOP_CACHE", "off")
    assert dop.config.cache_dir() is None


def test_cache_dir_is_created_and_checked(monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOP_CACHE", str(tmp_path / "a" / "b"))
    assert dop.config.cache_dir() == tmp_path / "a" / "b" and (tmp_path / "a" / "b").is_dir()
    assert list((tmp_path / "a" / "b").iterdir()) == []  # the write probe leaves nothing behind
    for off in ("off", "OFF", "0", "none", "false", "no"):
        monkeypatch.setenv("DEFOP_CACHE", off)
        assert dop.config.cache_dir() is None


def test_a_bad_cache_dir_names_defop_cache_and_the_path(monkeypatch, tmp_path):
    afile = tmp_path / "a-file"
    afile.write_text("x")
    cases = {
        afile: "is not a directory",
        afile / "sub": "cannot create the cache directory",
        Path("/proc/1"): "cannot write to the cache directory",  # exists, and no one may write there
    }
    for path, what in cases.items():
        monkeypatch.setenv("DEFOP_CACHE", str(path))
        with pytest.raises(ValueError, match="DEFOP_CACHE") as exc:
            dop.config.cache_dir()
        assert (
            f"DEFOP_CACHE='{path}'" in str(exc.value) and what in str(exc.value) and "DEFOP_CACHE=off" in str(exc.value)
        )


def test_the_default_cache_dir_is_checked_too(monkeypatch, tmp_path):
    monkeypatch.delenv("DEFOP_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / ".cache").write_text("a file where the folder should be")
    with pytest.raises(ValueError, match=r"the default DEFOP_CACHE: cannot create the cache directory .*\.cache/defop"):
        dop.config.cache_dir()


def test_n_jobs_from_the_environment(monkeypatch):
    monkeypatch.delenv("DEFOP_N_JOBS", raising=False)
    assert dop.config.n_jobs() == -1
    monkeypatch.setenv("DEFOP_N_JOBS", "3")
    assert dop.config.n_jobs() == 3
    for bad in ("0", "two", "1.5"):
        monkeypatch.setenv("DEFOP_N_JOBS", bad)
        with pytest.raises(ValueError, match=f"DEFOP_N_JOBS must be a non-zero integer .*, got '{bad}'"):
            dop.config.n_jobs()
