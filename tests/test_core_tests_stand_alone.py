"""The core's tests import the core alone: no ground tool and no plugin, at the top, inside a
function or in a program they run in a child Python; what needs the tools (the simulator, a
whole flight) is tested in ``tests/``. (Engines some of them match with are still built by the
repository's ``conftest.py`` through the tools' engine compiler: a fixture, not an import of
theirs.)"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CORE_TESTS = REPO / "core" / "tests"


def _outside_packages() -> list[str]:
    """The packages of the ground tools, the strategy plugins and the example plugins."""
    return sorted(
        init.parent.name
        for pattern in ("plugins/*/src/*/__init__.py", "tests/*/src/*/__init__.py")
        for init in REPO.glob(pattern)
    )


def _imports_of(text: str, packages: list[str]) -> list[str]:
    """Each line of ``text`` that imports one of ``packages`` (any indent: a program in a
    string counts), as written."""
    names = "|".join(map(re.escape, packages))
    pattern = re.compile(rf"^\s*(?:from|import)\s+(?:{names})\b.*$", re.MULTILINE)
    return [match.group(0).strip() for match in pattern.finditer(text)]


def test_the_outside_packages_are_found() -> None:
    packages = _outside_packages()
    assert {"c3_matcher_tools", "c3_matcher_disk_lightglue", "c3_matcher_xfeat"} <= set(packages)
    assert "c3_matcher" not in packages


def test_an_import_is_seen_at_the_top_in_a_function_and_in_a_program() -> None:
    text = (
        "from c3_matcher_tools.run import x\n"
        "def f():\n    import c3_matcher_tools\n"
        'PROGRAM = """\n    from c3_matcher_tools.testing.cli import run_cli\n"""\n'
        "from c3_matcher.testing.cli import run_cli  # the core's own\n"
        'OUTSIDE = ("c3_matcher_tools",)\n'
    )
    assert _imports_of(text, ["c3_matcher_tools"]) == [
        "from c3_matcher_tools.run import x",
        "import c3_matcher_tools",
        "from c3_matcher_tools.testing.cli import run_cli",
    ]


def test_no_core_test_imports_a_tool_or_a_plugin() -> None:
    packages = _outside_packages()
    sources = sorted(CORE_TESTS.rglob("*.py"))
    assert len(sources) > 100
    found = [
        f"{path.relative_to(REPO)}: {line}"
        for path in sources
        for line in _imports_of(path.read_text(encoding="utf-8"), packages)
    ]
    assert found == []
