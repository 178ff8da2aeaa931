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
    for extra in ("test", "notebook", "dev", "docs"):
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


def _requirements():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        reqs += extra
    return reqs


def test_constraints_pin_every_dependency_within_pyproject():
    """make installs with constraints.txt: every dependency pinned, each pin allowed by pyproject.toml."""
    from packaging.requirements import Requirement

    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not an exact pin"
            pins[_name(name)] = version.strip()
    assert "defop" not in pins, "the project itself is not pinned"
    for req in map(Requirement, _requirements()):
        name = _name(req.name)
        assert name in pins, f"{name} is not in constraints.txt: run make constraints"
        assert req.specifier.contains(pins[name], prereleases=True), f"{name}=={pins[name]} violates {req}"
    make = (ROOT / "Makefile").read_text()
    assert re.search(r"pip install .*-c \$\(CONSTRAINTS\)", make) and "CONSTRAINTS := constraints.txt" in make


def test_ipykernel_7_is_excluded_everywhere():
    """ipykernel 7 under nbclient intermittently never answers execute_reply: the main job hung."""
    from packaging.requirements import Requirement

    ipk = next(Requirement(r) for r in _requirements() if _name(r) == "ipykernel")
    assert not ipk.specifier.contains("7.4.0") and ipk.specifier.contains("6.31.0")
    assert re.search(r"^\s*- ipykernel>=6,<7", (ROOT / "environment.yml").read_text(), re.M)


def test_make_lab_opens_the_notebooks_and_allows_root():
    make = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^lab:.*\n((?:\t.*\n)+)", make, re.M)
    assert recipe and "cd notebooks" in recipe[1] and "jupyter lab" in recipe[1] and "--allow-root" in recipe[1]
    assert re.search(r"^\s*\$ make lab\s*$", (ROOT / "README.md").read_text(), re.M)
    assert re.search(r"^constraints:", make, re.M) and "pip freeze --exclude-editable" in make
