"""The package's architecture as checked properties: the subpackages, the import rule, no private reach-ins.

The layer rule itself is import-linter's (``[tool.importlinter]`` in pyproject.toml); this file runs it, so that
``pytest`` alone checks it too, and checks what import-linter does not: private names across subpackages, the
public face, that the core loads no plotting or widget library at run time, and the house's sizes (modules, functions,
classes).
"""

from __future__ import annotations

import ast
import functools
import inspect
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import defop as dop

PACKAGE = Path(dop.__file__).parent
CORE = ("geometry", "scene", "variational", "operator", "training", "rivals", "analysis")


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield path, ".".join(parts)


def _subpackage(module):
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _imports(path, module):
    """(target module, imported names, line) of every import in a file, relative ones resolved."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            yield target, [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, [], node.lineno


def _run_without_display(code, **env):
    """stdout of ``python -c code`` in a fresh interpreter without DISPLAY, with ``env`` added; fails on an error."""
    env = {**{k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}, **env}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_every_listed_subpackage_exists_and_imports():
    for name in dop._SUBPACKAGES:
        assert (PACKAGE / name / "__init__.py").exists() or (PACKAGE / f"{name}.py").exists(), name
        assert inspect.ismodule(getattr(dop, name))


def test_the_public_face():
    assert dop.shapes is dop.scene.shapes
    assert dop.solve is dop.variational.solver.solve
    assert dop.train is dop.training.bootstrap.train
    assert dop.DefOp is dop.operator.defop.DefOp
    assert dop.Mesh is dop.geometry.mesh.Mesh and dop.Shape is dop.scene.shapes.Shape
    with pytest.raises(AttributeError, match="module 'defop' has no attribute 'experiments'"):
        dop.experiments  # noqa: B018


def test_no_private_name_is_imported_from_another_module():
    """Splitting a module never opens its insides: a name that starts with an underscore is used only in the module
    that defines it (any other module, in its subpackage or not; ``__version__`` and other dunders aside)."""
    reach_ins = []
    for path, module in _modules():
        for target, names, line in _imports(path, module):
            if not target.startswith("defop") or target == module:
                continue
            private_module = any(p.startswith("_") and p != "__init__" for p in target.split(".")[1:])
            private_names = [n for n in names if n.startswith("_") and not n.startswith("__")]
            if private_module or private_names:
                reach_ins.append(f"{module}:{line} imports {target} {private_names}")
    assert reach_ins == []


def test_the_private_import_check_sees_a_reach_in_inside_a_subpackage(tmp_path):
    pkg = tmp_path / "defop" / "sub"
    pkg.mkdir(parents=True)
    (pkg / "a.py").write_text("def f():\n    from .b import _hidden\n")
    found = [t for t, names, _ in _imports(pkg / "a.py", "defop.sub.a") if any(n.startswith("_") for n in names)]
    assert found == ["defop.sub.b"]


#: the house's limits (CONTRIBUTING.md): modules under 500 lines, functions about 60
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 60

#: functions whose code (the docstring left out) is longer than MAX_FUNCTION_LINES, each with the reason it stays
#: whole; the list may only shrink (a test fails on an entry that is no longer long)
LONG_FUNCTIONS: dict[str, str] = {}


def test_no_module_is_over_500_lines():
    """Counted on the formatted source (``ruff format --check`` runs in make test), the vendored JavaScript aside."""
    over = {module: n for path, module in _modules() if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert over == {}


def _code_lines(path, module):
    """{qualified name: lines of code} of every function and method of a file, its docstring left out."""
    out = {}

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                body = child.body
                if len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                    body = body[1:]
                out[f"{prefix}{child.name}"] = child.end_lineno - body[0].lineno + 1
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")

    visit(ast.parse(path.read_text()), f"{module}.")
    return out


def _long_functions():
    return {q: n for path, module in _modules() for q, n in _code_lines(path, module).items() if n > MAX_FUNCTION_LINES}


def test_every_function_over_60_lines_is_listed_with_its_reason():
    assert sorted(set(_long_functions()) - set(LONG_FUNCTIONS)) == []


def test_the_list_of_long_functions_only_shrinks():
    assert sorted(set(LONG_FUNCTIONS) - set(_long_functions())) == []


def test_the_function_count_leaves_the_docstring_out(tmp_path):
    f = tmp_path / "m.py"
    f.write_text(
        'def f():\n    """doc\n\n    more"""\n' + "    a = 1\n" * 61 + "\n\nclass C:\n    def g(self):\n        pass\n"
    )
    assert _code_lines(f, "m") == {"m.f": 61, "m.C.g": 1}


def test_no_module_reaches_the_package_through_import_defop():
    """Hidden links: ``import defop as dop`` inside the package hides which layer a module uses."""
    hidden = [
        f"{module}:{line}"
        for path, module in _modules()
        for target, names, line in _imports(path, module)
        if target == "defop" and not names
    ]
    assert hidden == []


def test_the_import_contracts_hold():
    lint = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    if not Path(lint).exists():
        pytest.skip("import-linter is not installed (pip install -e '.[dev]')")
    root = PACKAGE.parent
    r = subprocess.run([lint, "--no-cache"], cwd=root, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "5 kept, 0 broken" in r.stdout


def test_the_core_loads_no_plotting_or_widget_library():
    """At run time, not only in the import graph: a shape, a solve and a training import nothing heavy."""
    code = (
        "import sys, numpy as np, defop as dop\n"
        "for sub in " + repr(CORE) + ": getattr(dop, sub)\n"
        "shape = dop.shapes.load('bar')\n"
        "r = dop.solve(shape.mesh, shape.handles, shape.targets(shape.P_moving + [[0.0, 0.05]]), energy='arap')\n"
        "loaded = [m for m in ('matplotlib', 'pyvista', 'vtk', 'ipywidgets', 'anywidget') if m in sys.modules]\n"
        "print(loaded)\n"
    )
    assert _run_without_display(code, DEFOP_CACHE="off").strip().splitlines()[-1] == "[]"


def test_every_name_in_every_subpackage_imports_without_a_display():
    """In a fresh interpreter without DISPLAY, so the lazy presentation modules are imported too."""
    code = (
        "import inspect, defop\n"
        "count = 0\n"
        "for sub in defop._SUBPACKAGES:\n"
        "    mod = getattr(defop, sub)\n"
        "    for n in dir(mod):\n"
        "        getattr(mod, n); count += 1\n"
        "print(count)\n"
    )
    assert int(_run_without_display(code, MPLBACKEND="Agg").split()[-1]) > 50


def _import_graph():
    """grimp's graph of the package (import-linter's), with the imports inside functions."""
    grimp = pytest.importorskip("grimp", reason="grimp comes with import-linter (pip install -e '.[dev]')")
    return grimp.build_graph("defop", cache_dir=None)


def _cycles(edges):
    """The strongly connected components of more than one module (or a module importing itself): Tarjan."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while not comp or comp[-1] != v:
                comp.append(stack.pop())
                on.discard(comp[-1])
            if len(comp) > 1 or v in edges.get(v, ()):
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}) == [["a", "b", "c"]]
    assert _cycles({"a": ["a"]}) == [["a"]] and _cycles({"a": ["b"], "b": []}) == []


def test_the_import_graph_has_no_cycles():
    """No import circle between modules, imports inside functions included (verify → newton was one, issue 35)."""
    graph = _import_graph()
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    assert _cycles(edges) == []


def test_the_import_graph_holds_the_imports_inside_functions():
    """What the cycle test sees: every defop import written inside a function is an edge of grimp's graph."""
    graph = _import_graph()
    inner = []
    for path, module in _modules():
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, ast.ImportFrom) and node.level:
                        inner.append((module, node.lineno))
    assert len(inner) > 10  # the lazy imports (plotting, optional back ends) are many
    missing = [
        (m, line)
        for m, line in inner
        if not any(
            d["line_number"] == line
            for t in graph.find_modules_directly_imported_by(m)
            for d in graph.get_import_details(importer=m, imported=t)
        )
    ]
    assert missing == []


#: classes whose size counts a base that is a class in its own right, not a mixin: HandleBasis, the abstract base of
#: all four handle bases (TPSBasis overrides 8 of its methods and is under 160 lines alone). Getting the pair under
#: 300 would move TPSBasis's fast raw-value methods out as functions only to pass this count, the method/function
#: doubles this rule is meant to prevent. Measured with the base on the formatted source, a ceiling that may only go
#: down. (Solver no longer inherits its problem: it holds one, 259 lines.)
OVER_WITH_BASES = {"defop.operator.handle_bases.TPSBasis": 317}
MAX_CLASS_LINES = 300


@functools.cache
def _formatted_spans(path):
    """{top-level class name: its lines} of a file as ``ruff format`` writes it (the house's formatted source)."""
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (pip install -e '.[dev]')")
    r = subprocess.run(
        [ruff, "format", "--stdin-filename", str(path), "-"],
        input=path.read_text(),
        capture_output=True,
        text=True,
        timeout=60,
        cwd=PACKAGE.parent,
    )
    assert r.returncode == 0, r.stderr
    tree = ast.parse(r.stdout)
    return {
        n.name: n.end_lineno - min([n.lineno, *(d.lineno for d in n.decorator_list)]) + 1
        for n in tree.body
        if isinstance(n, ast.ClassDef)
    }


@functools.lru_cache(maxsize=1)
def class_sizes():
    """{class: (lines, defop bases)} of every class in defop, with its defop bases and mixins counted with it."""
    import importlib

    spans, classes = {}, {}
    for path, module in _modules():
        if module.endswith("__main__"):
            continue
        spans[module] = _formatted_spans(path)
        mod = importlib.import_module(module)
        for name, cls in inspect.getmembers(mod, inspect.isclass):
            if cls.__module__ == module and name in spans[module]:
                classes[f"{module}.{name}"] = cls
    sizes = {}
    for qual, cls in classes.items():
        own = [c for c in cls.__mro__ if c.__module__.startswith("defop") and c.__qualname__ in spans[c.__module__]]
        sizes[qual] = (sum(spans[c.__module__][c.__qualname__] for c in own), [c.__qualname__ for c in own[1:]])
    return sizes


def test_no_class_is_over_300_lines():
    """A class with its defop bases and mixins, on formatted source (EditorState was 306, split into
    :mod:`defop.editor.state` and the pure functions of :mod:`defop.editor.logic`)."""
    sizes = class_sizes()
    assert "defop.editor.state.EditorState" in sizes and len(sizes) > 40
    over = {q: n for q, (n, _) in sizes.items() if n > OVER_WITH_BASES.get(q, MAX_CLASS_LINES)}
    assert over == {}
    for qual in OVER_WITH_BASES:  # over only with their base counted
        module, name = qual.rsplit(".", 1)
        assert _formatted_spans(PACKAGE.parent / (module.replace(".", "/") + ".py"))[name] <= MAX_CLASS_LINES


def test_the_class_size_check_counts_bases():
    sizes = class_sizes()
    n, bases = sizes["defop.operator.handle_bases.LinearBasis"]
    assert bases == ["PolynomialBasis", "HandleBasis"]
    alone = _formatted_spans(PACKAGE / "operator" / "handle_bases.py")
    assert n == alone["LinearBasis"] + alone["PolynomialBasis"] + alone["HandleBasis"]
