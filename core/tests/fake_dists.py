"""Fake installed distributions (``*.dist-info`` with ``entry_points.txt``) for plugin tests:
nothing is installed, the test's own directory is searched."""

from __future__ import annotations

import textwrap
from pathlib import Path

import importlib_metadata

WORKING_PLUGIN = """
from c3_matcher.plugins import StrategySpec, hookimpl

def create(**kwargs):
    raise AssertionError("not called in discovery tests")

@hookimpl
def c3_matcher_strategies():
    return [StrategySpec(name="{strategy}", factory=create, build_flag={flag!r},
                         description="a fake strategy")]
"""

BROKEN_PLUGIN = """
import module_that_does_not_exist  # noqa: F401
"""


def make_dist(
    root: Path,
    dist: str,
    module: str,
    source: str,
    *,
    group: str = "c3_matcher.plugins",
    ep_name: str | None = None,
    ep_value: str | None = None,
) -> None:
    """Write ``<dist>-1.0.dist-info`` and the module it points at into ``root``."""
    info = root / f"{dist.replace('-', '_')}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        f"[{group}]\n{ep_name or module} = {ep_value or module}\n"
    )
    (root / f"{module}.py").write_text(textwrap.dedent(source))


def dists(root: Path) -> list[importlib_metadata.Distribution]:
    return list(importlib_metadata.distributions(path=[str(root)]))
