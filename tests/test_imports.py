"""The package's import graph has no cycle (issue 16): every ``import loopid...`` anywhere in a
module, at its top or inside a function, is an edge; a cycle among them is a failure. An import
of a module's own ancestor package (``import loopid`` in ``loopid.experiments.execute``) is not
an edge: Python has imported the ancestors before the module, whatever it names."""

import ast
import sys
from pathlib import Path

import loopid

SRC = Path(loopid.__file__).resolve().parent


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """``{module: the loopid modules it names in an import}`` (``from a import b`` names
    ``a.b`` when that is a module, else ``a``)."""
    modules = {module_name(p): p for p in SRC.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                subs = [f"{node.module}.{a.name}" for a in node.names]
                targets = [m for m in subs if m in modules] or [node.module]
            graph[name] |= {
                t for t in targets if t in modules and t != name and not name.startswith(t + ".")
            }
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_is_read():
    graph = import_graph()
    assert "loopid.experiments.executors" in graph
    assert "loopid.algorithms.loop" in graph["loopid.experiments.families.helicopter.run"]


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle():
    assert cycles(import_graph()) == []


ENGINE = ("algorithms", "control", "learners", "models", "systems")


def _under(name: str, packages) -> bool:
    return any(name == f"loopid.{p}" or name.startswith(f"loopid.{p}.") for p in packages)


def test_the_layers_import_downwards_only():
    """The engine imports nothing of the settings, the round directories, the experiments or the
    command line; the settings only the engine and themselves; the round directories nothing of
    the experiments or the command line."""
    graph = import_graph()
    banned = {
        ENGINE: ("settings", "rounds", "experiments", "cli"),
        ("rounds",): ("experiments", "cli"),
    }
    found = {
        (m, t)
        for layer, above in banned.items()
        for m, targets in graph.items()
        if _under(m, layer)
        for t in targets
        if _under(t, above)
    }
    found |= {
        (m, t)
        for m, targets in graph.items()
        if _under(m, ("settings",))
        for t in targets
        if not _under(t, (*ENGINE, "settings"))
    }
    assert not found, sorted(found)


def test_the_settings_import_only_the_standard_library_and_numpy():
    """Besides loopid's engine (:func:`test_the_layers_import_downwards_only`)."""
    outside = set()
    for path in (SRC / "settings").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            top = {n.split(".")[0] for n in names}
            outside |= top - set(sys.stdlib_module_names) - {"numpy", "loopid"}
    assert not outside, outside
