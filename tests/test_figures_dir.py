"""Tests never write into the repository: only the main job's full runs write ``figures/``."""

from __future__ import annotations

import pathlib
import subprocess

import pytest

from defop import config, figures

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_figures_go_to_a_temporary_directory_unless_the_main_job_says_otherwise(tmp_path, monkeypatch):
    monkeypatch.delenv("DEFOP_FIGURES", raising=False)
    temp = config.figures_dir()
    assert temp.is_dir() and ROOT not in temp.resolve().parents and temp == config.figures_dir()
    monkeypatch.setenv("DEFOP_FIGURES", str(tmp_path / "made" / "figures"))
    assert config.figures_dir() == tmp_path / "made" / "figures" and (tmp_path / "made" / "figures").is_dir()
    (tmp_path / "a_file").write_text("x")
    monkeypatch.setenv("DEFOP_FIGURES", str(tmp_path / "a_file"))
    with pytest.raises(ValueError, match="DEFOP_FIGURES.*not a directory"):
        config.figures_dir()


def _status():
    run = subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        pytest.skip(f"not a git checkout: {run.stderr.strip()}")
    return run.stdout


def test_a_fast_run_of_a_notebook_leaves_the_repository_untouched(monkeypatch):
    monkeypatch.delenv("DEFOP_FIGURES", raising=False)
    shipped = {f.name: f.stat().st_mtime_ns for f in (ROOT / "figures").glob("*")}
    before = _status()
    figures.run_notebook(ROOT / "notebooks" / "00_shapes.ipynb", fast=True, store=False, progress=None)
    assert _status() == before
    assert {f.name: f.stat().st_mtime_ns for f in (ROOT / "figures").glob("*")} == shipped
