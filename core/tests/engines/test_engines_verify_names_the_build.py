"""``engines verify`` and ``engines list`` name, under each engine they fail, the command that
replaces it: the build of its model/variant, worded as start-up words it (``build it with
`c3-matcher engines build --only disk/depth```). An engine an earlier c3-matcher built (its
build key covered fewer fields) was refused by both with the reason alone, while ``match``
named the build.

A real DISK engine linked into a temporary directory beside a manifest written as an earlier
version wrote it: the same fields under another recorded key, the files named by that key."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.engines.naming import manifest_path_for

from .copies import link_or_copy, other_build

BUILD_DISK = "    build it with `c3-matcher engines build --only disk/depth`"


def _earlier_build(engine: Path, into: Path) -> Path:
    """``engine`` linked into ``into`` (made here) as an earlier c3-matcher built it: its
    manifest's fields unchanged, its recorded build key (and so its file name) another."""
    into.mkdir()
    return other_build(engine, into=into, build_key="85ec4024b9" + "0" * 54)


@pytest.fixture()
def earlier(disk_engine: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The engine directory set to one holding an earlier build of disk/depth alone."""
    engine = _earlier_build(disk_engine, tmp_path / "engines")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine.parent))
    return engine


def _under(lines: list[str], head: str) -> list[str]:
    """The indented lines that follow the line starting with ``head``."""
    (start,) = [i for i, line in enumerate(lines) if line.startswith(head)]
    rest = lines[start + 1 :]
    return rest[: next((i for i, line in enumerate(rest) if not line.startswith(" ")), None)]


def test_verify_names_the_build_of_an_engine_an_earlier_version_built(
    earlier: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["engines", "verify"]) == 1
    lines = capsys.readouterr().out.splitlines()
    head = f"FAIL {earlier.name}: its manifest {manifest_path_for(earlier).name} does not match"
    assert _under(lines, head) == [BUILD_DISK], lines


def test_verify_names_the_build_of_each_engine_missing(
    earlier: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["engines", "verify"]) == 1
    lines = capsys.readouterr().out.splitlines()
    head = "FAIL lightglue_disk_*_*_op*_*.onnx: missing: no valid lightglue/disk engine"
    assert _under(lines, head) == [
        "    build it with `c3-matcher engines build --only lightglue/disk`"
    ], lines


def test_verify_of_intact_engines_names_no_build(
    disk_engine: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    into = tmp_path / "engines"
    into.mkdir()
    for path in (disk_engine, manifest_path_for(disk_engine)):
        link_or_copy(path, into / path.name)
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(into))
    assert main(["engines", "verify"]) == 1  # the other engines the plugins declare are missing
    lines = capsys.readouterr().out.splitlines()
    assert _under(lines, f"OK   {disk_engine.name}: sha256") == []


def test_list_names_the_build_of_an_engine_an_earlier_version_built(
    earlier: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["engines", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    under = _under(lines, f"{earlier.name}  [PROBLEM: its manifest")
    assert under[0] == BUILD_DISK, lines
    assert under[1].startswith("    disk/depth extractor fp32")  # the manifest still shown
