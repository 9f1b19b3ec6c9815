"""The core names no plugin and no ground tool: they plug into it through its hooks, and it
finds their engines by their manifests."""

from __future__ import annotations

from pathlib import Path

CORE_SRC = Path(__file__).resolve().parents[1] / "src"
OUTSIDE = (
    "c3_matcher_tools",
    "c3_matcher_disk_lightglue",
    "c3_matcher_aliked_lightglue",
    "c3_matcher_xfeat",
)


def test_no_core_module_names_a_plugin_or_the_tools() -> None:
    sources = sorted(CORE_SRC.rglob("*.py"))
    assert len(sources) > 20
    named = [
        f"{path.relative_to(CORE_SRC)}: {name}"
        for path in sources
        for name in OUTSIDE
        if name in path.read_text(encoding="utf-8")
    ]
    assert named == []


MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60


def test_the_core_stays_in_small_pieces() -> None:
    """No core module over 400 lines, no function over 60 (``def`` to its last line): what
    the core's layout promises, kept as it grows (a sidecar module passed 400 unnoticed)."""
    import ast

    sources = sorted(CORE_SRC.rglob("*.py"))
    long_modules = [
        f"{p.relative_to(CORE_SRC)}: {n} lines"
        for p in sources
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    ]
    long_functions = [
        f"{p.relative_to(CORE_SRC)}:{node.lineno} {node.name}: {length} lines"
        for p in sources
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and (length := (node.end_lineno or node.lineno) - node.lineno + 1) > MAX_FUNCTION_LINES
    ]
    assert long_modules == [] and long_functions == []
