"""Every name the package lists imports (documentation tools and ``inspect.getmembers`` walk them all)."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from pathlib import Path

import pytest

import defop as dop


def test_every_listed_submodule_exists():
    here = Path(dop.__file__).parent
    missing = [name for name in dop._SUBMODULES if not (here / f"{name}.py").exists()]
    assert missing == []


def test_every_name_in_dir_defop_imports_without_a_display():
    """In a fresh interpreter without DISPLAY, so the lazy presentation modules are imported too."""
    code = (
        "import inspect, defop\n"
        "names = dir(defop)\n"
        "for n in names: getattr(defop, n)\n"
        "members = dict(inspect.getmembers(defop))\n"
        "assert set(names) <= set(members), set(names) - set(members)\n"
        "print(len(names))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MPLBACKEND"] = "Agg"
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.split()[-1]) >= len(dop._SUBMODULES)


def test_getmembers_and_missing_names():
    names = dict(inspect.getmembers(dop))
    assert set(dop._SUBMODULES) <= set(names) and "experiments" not in names
    with pytest.raises(AttributeError, match="module 'defop' has no attribute 'experiments'"):
        dop.experiments  # noqa: B018
