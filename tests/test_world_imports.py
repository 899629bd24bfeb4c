"""The modules of ``twin.world`` import each other without cycles (function-level imports included)."""

import ast
from pathlib import Path

import twin.world

PKG = Path(twin.world.__file__).resolve().parent


def _module_graph(folder: Path) -> dict[str, set[str]]:
    """Intra-package import edges ``module -> {modules}`` of every ``*.py`` in ``folder`` (any nesting level)."""
    mods = {p.stem for p in folder.glob("*.py")}
    graph: dict[str, set[str]] = {}
    for p in folder.glob("*.py"):
        edges: set[str] = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                if node.module:
                    edges.add(node.module.split(".")[0])
                else:  # from . import a, b
                    edges.update(a.name for a in node.names)
        graph[p.stem] = {e for e in edges if e in mods and e != p.stem}
    return graph


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_world_package_has_no_import_cycle():
    """No module of twin/world imports (even lazily) a module that imports it back."""
    graph = {k: v for k, v in _module_graph(PKG).items() if k != "__init__"}
    assert _find_cycle(graph) is None, f"import cycle: {' -> '.join(_find_cycle(graph))}"


def test_cycle_finder_can_fail():
    """The checker reports a cycle when there is one (truth -> world -> truth)."""
    assert _find_cycle({"truth": {"world"}, "world": {"truth", "records"}, "records": set()}) == [
        "truth", "world", "truth"]
