"""The tree stays in small pieces as it grows: every function under 60 lines (``def`` to its
last line) in the core, the ground tools and every strategy plugin, no core module over 400
lines and no module of the ground tools or a plugin over 500 (a core module passed 400
unnoticed; the tools' long exporters and planners were split, then the flight renderer, the
test log writers, the GeoTIFF grids and the HTML report; the command line's one function of
exactly 60 lines passed a gate that counted 60 as under)."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORE_SRC = REPO / "core" / "src"
MAX_CORE_MODULE_LINES = 400
MAX_PLUGIN_MODULE_LINES = 500
FUNCTION_LINES_UNDER = 60


def _plugin_sources() -> list[Path]:
    """Every module of the ground tools and the strategy plugins."""
    return sorted(REPO.glob("plugins/*/src/**/*.py"))


def _sources() -> list[Path]:
    return sorted(CORE_SRC.rglob("*.py")) + _plugin_sources()


def _longer_than(paths: list[Path], max_lines: int) -> list[str]:
    """``path: n lines`` of each module of ``paths`` over ``max_lines``."""
    return [
        f"{p.relative_to(REPO)}: {n} lines"
        for p in paths
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > max_lines
    ]


def test_every_function_is_under_60_lines() -> None:
    sources = _sources()
    assert len(sources) > 100
    long_functions = [
        f"{p.relative_to(REPO)}:{node.lineno} {node.name}: {length} lines"
        for p in sources
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and (length := (node.end_lineno or node.lineno) - node.lineno + 1) >= FUNCTION_LINES_UNDER
    ]
    assert long_functions == []


def test_no_core_module_is_longer_than_400_lines() -> None:
    assert _longer_than(sorted(CORE_SRC.rglob("*.py")), MAX_CORE_MODULE_LINES) == []


def test_no_tool_or_plugin_module_is_longer_than_500_lines() -> None:
    sources = _plugin_sources()
    assert len(sources) > 100
    assert _longer_than(sources, MAX_PLUGIN_MODULE_LINES) == []
