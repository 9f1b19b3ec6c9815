"""A plugin that declares no engines of its own and whose options do not choose the pair matcher
(the example plugin, ``tests/example_plugin``: the DISK plugin's DISK and LightGlue engines,
taken by their specs) may read ``[lightglue]``, and does: nothing says its run is the same
without a value set there, and its report records them. Its ``filter_threshold = 0.9`` changed
its result while start-up warned that it was not read, ``config`` said the same, and the report
recorded ``lightglue_settings: {}``."""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path

import pytest

from c3_matcher.cli import main

from .conftest import SmallFlight

EXAMPLE = Path(__file__).resolve().parents[3] / "tests" / "example_plugin"
STRATEGY = "example_fast_disk"
UNREAD = "does not match with LightGlue"


@pytest.fixture
def example_installed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    """The example plugin installed in this process as pip installs it in place: its package
    on the path, and its distribution's metadata (name, version, the entry point its
    ``pyproject.toml`` declares) where plugin discovery finds it; no ``C3_MATCHER_`` variable of
    the caller's. Returns ``monkeypatch``."""
    project = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]
    name, version = project["name"], project["version"]
    info = tmp_path / "site" / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    info.joinpath("METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
    )
    points = project["entry-points"]
    info.joinpath("entry_points.txt").write_text(
        "".join(
            f"[{group}]\n" + "".join(f"{key} = {value}\n" for key, value in entries.items())
            for group, entries in points.items()
        )
    )
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    monkeypatch.syspath_prepend(str(info.parent))
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    monkeypatch.setenv("C3_MATCHER_LIGHTGLUE__FILTER_THRESHOLD", "0.9")
    return monkeypatch


def test_config_does_not_say_the_examples_lightglue_settings_are_unread(
    example_installed: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    example_installed.setenv("C3_MATCHER_MATCHER__STRATEGY", STRATEGY)
    assert main(["config"]) == 0, capsys.readouterr().err
    out, err = capsys.readouterr()
    assert UNREAD not in err and UNREAD not in out, err
    lines = out.splitlines()
    at = lines.index("[lightglue]")
    assert lines[at + 1].startswith(f"# strategy {STRATEGY} declares neither its pair matcher")
    assert "filter_threshold = 0.9" in lines[at:]


def test_the_examples_run_is_not_warned_and_its_report_records_its_lightglue_settings(
    example_installed: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    small_flight: SmallFlight,
    engine_dir: Path,
) -> None:
    example_installed.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    flight, out = small_flight("naip_demo"), tmp_path / "run"
    argv = ["replay", str(flight), "--limit", "1", "--strategy", STRATEGY, "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err[-2000:]
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["strategy"] == STRATEGY
    assert report["lightglue_settings"]["filter_threshold"] == 0.9
    logged = [json.loads(line) for line in (out / "matcher.log").read_text().splitlines()]
    assert [r for r in logged if r["kind"] == "c3.config.ignored"] == []
    assert any(r["kind"] == "c3.lightglue.engine_loaded" for r in logged)  # it does read them
