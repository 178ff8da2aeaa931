"""The sample engine (defop/training/solves.py, portfolios.py) is the only code that solves problem (6) for many
samples: a solver call (``Solver(...)``, ``.solve(...)``, ``solve_best(...)``) inside a loop, a comprehension or a
function handed to a parallel map, anywhere else in the library, is a batch solve written outside the engine.

The allowlist may only shrink: an entry that no longer finds a batch solve fails too, so it is removed when its
code moves onto the engine.
"""

from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "defop"

#: the engine's modules, and the solver itself (its multi-start loops over the starts of one sample)
ENGINE = ("defop/training/solves.py", "defop/training/paths.py", "defop/training/portfolios.py", "defop/variational/")

#: path prefix -> why its batch solves stay for now (only ever remove entries)
ALLOWED = {
    "defop/analysis/mountain_pass.py": "the saddle probe: single interactive solves along one mountain pass",
}

LOOPS = (ast.For, ast.AsyncFor, ast.While, ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)
MAPS = {"parallel_map", "map_checkpointed", "map", "delayed", "Parallel", "imap", "starmap", "submit"}
#: receivers whose ``.solve`` is linear algebra or the engine itself, not a solve of problem (6)
NOT_SOLVERS = ("linalg", "lu", "splu", "factor", "chol", "solves")


def _dotted(node):
    """``a.b.c`` of a Name/Attribute chain ("" for anything else)."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return f"{base}.{node.attr}" if base else node.attr
    return ""


def is_solver_call(call):
    """Does this call build a solver or solve problem (6)?"""
    f = call.func
    name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
    if name in ("Solver", "solve_best"):
        return True
    if name == "solve" and isinstance(f, ast.Attribute):
        receiver = _dotted(f.value).split(".")
        return not any(part in NOT_SOLVERS for part in receiver)
    return False


def _mapped_functions(tree):
    """Names of functions handed to a parallel map (directly or through ``functools.partial``)."""
    out = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func).split(".")[-1]
        if name not in MAPS:
            continue
        for arg in node.args[:1]:
            if isinstance(arg, ast.Call) and _dotted(arg.func).split(".")[-1] == "partial" and arg.args:
                arg = arg.args[0]
            if isinstance(arg, (ast.Name, ast.Attribute)):
                out.add(_dotted(arg).split(".")[-1])
    return out


def _solving_functions(tree, known=()):
    """Names of the module's functions that solve: a solver call in their body, or a call of such a function
    (transitively; ``known``: the names of the library's other functions that solve)."""
    bodies = {f.name: f for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))}
    calls = {name: [c for c in ast.walk(f) if isinstance(c, ast.Call)] for name, f in bodies.items()}
    solving = {name for name, cs in calls.items() if any(is_solver_call(c) or _callee(c) in known for c in cs)}
    while True:
        more = {name for name, cs in calls.items() if any(_callee(c) in solving for c in cs)} - solving
        if not more:
            return solving
        solving |= more


def _callee(call):
    f = call.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""


def batch_solves(source, known=()):
    """(line, reason) of every solve (a solver call, or a call of a function that solves: of this module, or one of
    ``known`` imported by name) in a loop, a comprehension or a function handed to a parallel map."""
    tree = ast.parse(source)
    imported = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    known = set(known) & imported  # another module's solving function, imported by name
    mapped, solving = _mapped_functions(tree), _solving_functions(tree, known) | known
    found = []

    def visit(node, in_loop, func):
        for child in ast.iter_child_nodes(node):
            loop, fn = in_loop, func
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                loop, fn = False, child.name
            elif isinstance(child, LOOPS):
                loop = True
            if isinstance(child, ast.Call) and (is_solver_call(child) or _callee(child) in solving):
                if in_loop:
                    found.append((child.lineno, "in a loop or comprehension"))
                elif fn in mapped:
                    found.append((child.lineno, f"in {fn}, handed to a parallel map"))
            visit(child, loop, fn)

    visit(tree, False, None)
    return found


def _library():
    """(path, source, the names of the library's solving functions) of every module outside the engine."""
    sources = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if not rel.startswith(ENGINE):
            sources[rel] = path.read_text(encoding="utf-8")
    known = set()
    for source in sources.values():
        known |= _solving_functions(ast.parse(source))
    for rel, source in sources.items():
        yield rel, source, known


def test_only_the_engine_solves_batches():
    bad = []
    for rel, source, known in _library():
        if any(rel.startswith(prefix) for prefix in ALLOWED):
            continue
        bad += [f"{rel}:{line}: solve {why}" for line, why in batch_solves(source, known)]
    assert not bad, "batch solves outside the sample engine (defop.training.solves):\n" + "\n".join(bad)


@pytest.mark.parametrize("prefix", sorted(ALLOWED))
def test_the_allowlist_only_shrinks(prefix):
    """Every allowlisted path still holds a batch solve: once it moves onto the engine, remove its entry."""
    hits = [rel for rel, source, known in _library() if rel.startswith(prefix) and batch_solves(source, known)]
    assert hits, f"{prefix} has no batch solve left: remove it from ALLOWED ({ALLOWED[prefix]})"


@pytest.mark.parametrize(
    "code, found",
    [
        ("for q in Q:\n    s.solve(T)", 1),
        ("X = [s.solve_best(t) for t in T]", 1),
        ("def f(jobs):\n    return s.solve(jobs[0])\nparallel_map(f, items)", 1),
        ("def f(s, jobs):\n    return Solver(m, h)\nparallel_map(functools.partial(f, s), items)", 1),
        ("while True:\n    r = dop.solve(mesh, h, T)", 1),
        ("r = s.solve(T)", 0),  # one interactive solve
        ("for a in A:\n    np.linalg.solve(a, b)\n    lu.solve(b)", 0),  # linear algebra
        ("for q in Q:\n    solves.solve(shape, q)", 0),  # the engine itself
        ("def one(s, t):\n    return s.solve_best(t)\ndef many(s, T):\n    return [one(s, t) for t in T]", 1),
        ("def one(s, t):\n    return s.solve_best(t)\nparallel_map(one, T)", 1),
        ("from .m import one\nfor t in T:\n    one(s, t)", 1),  # a solving function of another module
        ("for t in T:\n    m.one(s, t)\n    two(s, t)", 0),  # by attribute, or not imported: not seen
    ],
)
def test_the_rule_sees_batch_solves(code, found):
    assert len(batch_solves(code, {"one"})) == found
