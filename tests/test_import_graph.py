"""The modules import one another in layers: no circle of imports in the core, the ground tools
or any strategy plugin. Every import counts, whether at the top, under ``TYPE_CHECKING`` or
inside a function: an import deferred to dodge a circle still ties the two modules."""

from __future__ import annotations

import ast
from collections.abc import Mapping
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SOURCE_ROOTS = [REPO / "core" / "src", *sorted(REPO.glob("plugins/*/src"))]


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the source roots."""
    modules: dict[str, Path] = {}
    for root in SOURCE_ROOTS:
        for path in sorted(root.rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    return modules


def _imported(name: str, path: Path, modules: Mapping[str, Path]) -> set[str]:
    """The modules of the tree that ``name`` imports: ``from a import b`` is ``a.b`` when that is
    a module, else ``a``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0]
                base = f"{anchor}.{base}" if base else anchor
            found.update(
                f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names
            )
    return {m for m in found if m in modules and m != name}


def _graph(modules: Mapping[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules of the tree it imports."""
    return {name: _imported(name, path, modules) for name, path in modules.items()}


def _circles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_graph_sees_the_imports() -> None:
    graph = _graph(_modules())
    assert len(graph) > 150
    assert "c3_matcher.dto.geo" in graph["c3_matcher.dto.candidates"]
    assert "c3_matcher.engines.spec" in graph["c3_matcher.engines.lightglue_specs"]


def test_a_circle_is_found() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _circles(graph) == [["a", "b", "c"]]


def test_no_modules_import_each_other_in_a_circle() -> None:
    graph = _graph(_modules())
    circles = [
        f"{' <-> '.join(circle)}: "
        + "; ".join(f"{m} -> {', '.join(sorted(graph[m] & set(circle)))}" for m in circle)
        for circle in _circles(graph)
    ]
    assert circles == []
