"""pyproject.toml and environment.yml name the same packages; the README's two commands exist."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _name(req: str) -> str:
    return re.split(r"[<>=!~\[; ]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_environment_yml_matches_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = {_name(r) for r in project["dependencies"]}
    extras = project["optional-dependencies"]
    for extra in ("test", "notebook", "dev"):
        wanted |= {_name(r) for r in extras[extra]}
    text = (ROOT / "environment.yml").read_text().split("dependencies:", 1)[1]
    deps = [ln.strip()[2:].strip() for ln in text.splitlines() if ln.strip().startswith("- ")]
    named = {_name(d) for d in deps if d not in ("pip", "pip:", "-e .") and not d.startswith(("python", "-e"))}
    assert named == wanted, f"only in pyproject: {wanted - named}; only in environment.yml: {named - wanted}"


def test_nbval_0_10_is_excluded():
    test_extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    nbval = next(r for r in test_extra if _name(r) == "nbval")
    assert ">=0.11" in nbval


def test_readme_gives_the_two_commands_and_ci_uses_the_test_one():
    readme = (ROOT / "README.md").read_text()
    assert re.search(r"^\s*\$ make figures\s*$", readme, re.M)
    assert re.search(r"^\s*\$ make test\s*$", readme, re.M)
    ci = (ROOT / ".ci" / "run").read_text()
    assert "README.md" in ci and "--nbval" not in ci  # CI runs the README's command, not its own variant
    make = (ROOT / "Makefile").read_text()
    assert "--nbval-lax" in make and "--nbval-cell-timeout" in make and "--nbval-sanitize-with" in make
