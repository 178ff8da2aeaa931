"""Moved modules: the rival methods (defop.rivals), the lessons' data (defop.lessons), the 3D patch sampling
(defop.training.sampling) and the mountain pass (defop.analysis.mountain_pass). Their old names still work, each
with a DeprecationWarning naming the new home, and the shims are the import rule's only exceptions."""

from __future__ import annotations

import importlib
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

import defop as dop
from defop import lazy

ROOT = Path(dop.__file__).parent.parent

#: (old module, name, new module): one or more names per moved module
MOVED = [
    ("defop.analysis.peers", "make_peers", "defop.rivals.peers"),
    ("defop.analysis.peers", "Peer", "defop.rivals.peers"),
    ("defop.analysis.peers", "KINDS", "defop.rivals.peers"),
    ("defop.analysis.peers", "mls_precompute", "defop.rivals.closed_forms"),
    ("defop.analysis.peers", "ARAPIterations", "defop.rivals.libigl"),
    ("defop.variational.baselines", "solve_lbfgs", "defop.rivals.baselines"),
    ("defop.variational.baselines", "start_for", "defop.rivals.baselines"),
    ("defop.variational", "solve_lbfgs", "defop.rivals.baselines"),
    ("defop.variational", "solve_libigl_arap", "defop.rivals.baselines"),
    ("defop.variational", "start_for", "defop.rivals.baselines"),
    ("defop.analysis.figure_data", "local_rotation", "defop.lessons.figure_data"),
    ("defop.analysis.figure_data", "grid_error", "defop.lessons.figure_data"),
    ("defop.analysis.figure_data", "patch_motions", "defop.training.sampling"),
    ("defop.analysis.figure_data", "twist_bend_samples", "defop.training.sampling"),
    ("defop.analysis.random_branches", "random_cases", "defop.lessons.random_branches"),
    ("defop.analysis.random_branches", "VERTICES", "defop.lessons.random_branches"),
    ("defop.analysis.saddle", "mountain_pass", "defop.analysis.mountain_pass"),
    ("defop.analysis.saddle", "Saddle", "defop.analysis.mountain_pass"),
]


@pytest.mark.parametrize(("old", "name", "new"), MOVED)
def test_an_old_name_warns_and_is_the_new_object(old, name, new):
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=rf"{old}\.{name} is deprecated.*use {new}\.{name}") as record:
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)
    assert Path(record[0].filename) == Path(__file__)  # the warning points at the code that reads the old name


@pytest.mark.parametrize("old", sorted({m for m, _, _ in MOVED} - {"defop.variational"}))
def test_an_old_module_lists_its_moved_names_and_refuses_others(old):
    module = importlib.import_module(old)
    names = {n for m, n, _ in MOVED if m == old}
    assert names <= set(dir(module))
    with pytest.raises(AttributeError, match=rf"module '{old}' has no attribute 'no_such_name'"):
        module.no_such_name  # noqa: B018


def test_the_old_subpackage_attributes_still_reach_the_moved_modules():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # reaching the old module itself does not warn: only its names do
        assert dop.analysis.peers.__name__ == "defop.analysis.peers"
        assert dop.variational.baselines.__name__ == "defop.variational.baselines"
    assert dop.analysis.mountain_pass is importlib.import_module("defop.analysis.mountain_pass")
    assert (
        dop.rivals.make_peer is dop.rivals.peers.make_peer
        and dop.rivals.solve_lbfgs is dop.rivals.baselines.solve_lbfgs
    )
    assert dop.lessons.figure_data.local_rotation.__module__ == "defop.lessons.figure_data"
    assert dop.training.sampling.patch_motions.__module__ == "defop.training.sampling"


def test_the_new_homes_do_not_carry_the_moved_names_twice():
    assert not hasattr(importlib.import_module("defop.lessons.figure_data"), "patch_motions")
    assert "solve_lbfgs" not in dop.variational.__all__


def test_importing_the_packages_warns_about_nothing():
    """Only reading an old name warns: a fresh interpreter imports every package with DeprecationWarning an error."""
    code = "import defop.variational, defop.analysis, defop.rivals.peers, defop.lessons.figure_data, defop.training"
    r = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]


def test_moved_forwards_only_the_names_given():
    getattr_, dir_ = lazy.moved("old.place", "new.place", lambda: dop.training.sampling, names=("patch_motions",))
    assert dir_() == ["patch_motions"]
    with pytest.raises(AttributeError, match="module 'old.place' has no attribute 'sample_handles'"):
        getattr_("sample_handles")


def _contracts():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]


def test_the_import_rule_excepts_only_the_deprecation_shims():
    """Every ignored import starts in a module whose docstring says it is deprecated (a shim to be removed)."""
    ignored = [rule for c in _contracts() for rule in c.get("ignore_imports", [])]
    assert ignored  # the shims of this move
    for rule in ignored:
        source = rule.split(" -> ")[0]
        doc = importlib.import_module(source).__doc__ or ""
        if source == "defop.variational":
            doc = importlib.import_module(source).__getattr__.__doc__ or ""
        assert "deprecated" in doc.lower(), rule


def test_the_rivals_and_the_lessons_have_their_place_in_the_layers():
    layers = next(c for c in _contracts() if c["type"] == "layers")["layers"]
    at = {name.strip(): i for i, layer in enumerate(layers) for name in layer.split("|")}
    assert at["defop.rivals"] == at["defop.training"] < at["defop.variational"] == at["defop.operator"]
    assert at["defop.figures"] < at["defop.lessons"] < at["defop.analysis"] < at["defop.rivals"]
    forbidden = [c for c in _contracts() if c["type"] == "forbidden"]
    assert any(c["forbidden_modules"] == ["defop.rivals"] for c in forbidden)
    assert any(c["forbidden_modules"] == ["defop.lessons"] for c in forbidden)
    plotting = next(c for c in forbidden if "matplotlib" in c["forbidden_modules"])
    assert "defop.rivals" in plotting["source_modules"]
