from __future__ import annotations

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
