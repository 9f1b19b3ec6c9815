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
