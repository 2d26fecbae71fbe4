"""The package's shape (issue 36): no import cycle among `rigidjax`'s modules, no module over 500
lines. Pure `ast` and file reading: nothing of `rigidjax` is imported.

An import counts wherever it stands, at module level or inside a function (a function-level import
that goes back up is a circle too); only those under `if TYPE_CHECKING:` are left out. A
`from package import name` where `name` is a submodule counts as importing that submodule (not the
package's `__init__`, which every submodule's import runs anyway).

The known offenders that other changes are fixing stand in explicit allowlists. The tests assert
that each allowlist is exactly the current offenders: a new offender fails, and so does one that
has been fixed while still listed (take it off the list).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

PACKAGE = "rigidjax"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE
MAX_LINES = 500

# Import cycles still there (each a set of modules in one strongly connected component).
KNOWN_CYCLES: set[frozenset[str]] = set()

# Modules still over MAX_LINES (paths relative to the repository root).
KNOWN_LONG: set[str] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement of `tree`, at any depth, except under `if TYPE_CHECKING:`."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def _targets(
    node: ast.Import | ast.ImportFrom, module: str, is_package: bool, modules: set[str]
) -> set[str]:
    """The `rigidjax` modules that the import `node` in `module` imports."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
        return {n for n in names if n in modules}
    if node.level:
        base = module.split(".")
        base = base if is_package else base[:-1]
        base = base[: len(base) - (node.level - 1)]
        source = ".".join([*base, *([node.module] if node.module else [])])
    else:
        source = node.module or ""
    if source != PACKAGE and not source.startswith(PACKAGE + "."):
        return set()
    found = set()
    for alias in node.names:
        sub = f"{source}.{alias.name}"
        found.add(sub if sub in modules else source)
    return {m for m in found if m in modules}


def import_graph() -> dict[str, set[str]]:
    """`module → the rigidjax modules it imports` (self-imports left out)."""
    modules = _modules()
    names = set(modules)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        is_package = path.name == "__init__.py"
        edges: set[str] = set()
        for node in _imports(tree):
            edges |= _targets(node, module, is_package, names)
        graph[module] = edges - {module}
    return graph


def cycles(graph: dict[str, set[str]]) -> set[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: set[frozenset[str]] = set()
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = set()
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.add(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.add(frozenset(component))
    return found


def _one_cycle(graph: dict[str, set[str]], component: frozenset[str]) -> list[str]:
    """A closed path through `component`, for the failure message: `a → b → … → a`."""
    start = min(component)
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & component):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return [*reversed(path), start]
                if w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    return [start]


def test_graph_reads_the_package():
    graph = import_graph()
    assert "rigidjax.rotations.quat" in graph
    assert "rigidjax.rotations.quat" in graph["rigidjax.rotations"]


def test_no_import_cycles():
    graph = import_graph()
    found = cycles(graph)
    new = found - KNOWN_CYCLES
    fixed = KNOWN_CYCLES - found
    lines = [" → ".join(_one_cycle(graph, c)) for c in sorted(new, key=sorted)]
    assert not new, "import cycles among rigidjax modules:\n  " + "\n  ".join(
        f"{sorted(c)}: {line}" for c, line in zip(sorted(new, key=sorted), lines, strict=True)
    )
    assert not fixed, f"fixed, take them off KNOWN_CYCLES: {[sorted(c) for c in fixed]}"


def test_no_long_modules():
    counts = {
        str(p.relative_to(ROOT.parent)): len(p.read_text(encoding="utf-8").splitlines())
        for p in _modules().values()
    }
    long = {p for p, n in counts.items() if n > MAX_LINES}
    new = sorted(long - KNOWN_LONG)
    fixed = sorted(KNOWN_LONG - long)
    assert not new, f"modules over {MAX_LINES} lines: {[(p, counts[p]) for p in new]}"
    assert not fixed, f"now at most {MAX_LINES} lines, take them off KNOWN_LONG: {fixed}"


def test_cycle_finder():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}}
    assert cycles(graph) == {frozenset("abc")}
    assert _one_cycle(graph, frozenset("abc")) == ["a", "b", "c", "a"]


def test_simulate_is_a_front_door():
    """`simulate` only dispatches (issue 36): its body, docstring aside, at most 60 lines; the
    path is chosen below it (`mechanics/_rigid.py`, `_paths.py`, `models/solve.py`)."""
    tree = ast.parse((ROOT / "mechanics" / "dynamics.py").read_text())
    (fn,) = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "simulate"]
    body = fn.body[1:] if ast.get_docstring(fn) else fn.body
    lines = body[-1].end_lineno - body[0].lineno + 1  # pyright: ignore[reportOptionalOperand]
    assert lines <= 60, f"simulate's body has {lines} lines"
