"""The ``features build`` command a run prints when its store's map features served it nothing
builds the set that run asks for: on a copy of the demo flight whose sidecar holds XFeat's set
of the default settings, a replay given ``--config`` (photometric grey) prints a command that
carries the same ``--config``, and running it makes the next replay served; the line names the
set asked for and those held. Settings from ``C3_MATCHER_*`` variables, which no command line
carries, are named for the build to run with (those of no setting that keys a set are not).
``features info`` given ``--config`` prints its command with it too; a path with a space stays
one word of the command."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.features.command import build_command, given_settings
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
GREY = '[matcher]\nphotometric = "grey"\n'
ASKS_FOR = "build the one this run asks for: "


@pytest.fixture
def held(tmp_path: Path, engine_dir: Path) -> Path:
    """A copy of the demo flight whose store holds XFeat's set of its candidates' windows at
    the default settings (photometric none), and ``grey.toml`` beside it."""
    flight = tmp_path / "flt"
    shutil.copytree(FLIGHT, flight)
    _ok(
        "features", "build", "flt", "--strategy", "xfeat", "--workers", "0",
        "--flight-candidates", cwd=tmp_path, engine_dir=engine_dir,
    )  # fmt: skip
    (tmp_path / "grey.toml").write_text(GREY)
    return flight


def _ok(*args: str, cwd: Path, engine_dir: Path, settings: dict[str, str] | None = None) -> Any:
    proc = run_cli(*args, cwd=cwd, engine_dir=engine_dir, settings=settings)
    assert proc.returncode == 0, proc.stderr
    return proc


def _replay(cwd: Path, engine_dir: Path, out: str, *config: str, **settings: str) -> Any:
    """A replay of two frames of ``flt`` (``config``: the global options before it): its
    process and the candidates counted by where their features came from."""
    proc = _ok(
        *config, "replay", "flt", "--strategy", "xfeat", "--limit", "2", "--out", out,
        cwd=cwd, engine_dir=engine_dir, settings=settings,
    )  # fmt: skip
    return proc, json.loads((cwd / out / "report.json").read_text())["feature_sources"]


def _said(stderr: str) -> str:
    (line,) = [line for line in stderr.splitlines() if ASKS_FOR in line]
    return line


def _command(line: str) -> list[str]:
    """The words of the command the line prints, up to the note in brackets after it."""
    text = line.split(ASKS_FOR, 1)[1].split(" (", 1)[0].rstrip(".")
    return shlex.split(text)


@pytest.mark.slow
def test_the_printed_command_carries_the_config_and_serves_the_next_run(
    held: Path, engine_dir: Path
) -> None:
    cwd = held.parent
    proc, counts = _replay(cwd, engine_dir, "r1", "--config", "grey.toml")
    assert counts["stored"] == 0
    line = _said(proc.stderr)
    words = _command(line)
    assert words[:5] == ["c3-matcher", "--config", "grey.toml", "features", "build"], line
    assert ":grey:" in line and ":none:" in line, line  # the set asked for, the set held
    assert "`c3-matcher --config grey.toml features info flt`" in line, line
    assert "C3_MATCHER_MATCHER" not in line  # nothing of the settings from the environment

    _ok(*words[1:], "--flight-candidates", "--workers", "0", cwd=cwd, engine_dir=engine_dir)
    proc, counts = _replay(cwd, engine_dir, "r2", "--config", "grey.toml")
    assert counts["stored"] > 0 and counts["extracted"] == 0, counts
    assert ASKS_FOR not in proc.stderr


@pytest.mark.slow
def test_settings_from_the_environment_are_named_for_the_build(
    held: Path, engine_dir: Path
) -> None:
    variable = "C3_MATCHER_MATCHER__PHOTOMETRIC"
    unrelated = "C3_MATCHER_LOGGING__LEVEL"
    proc, counts = _replay(held.parent, engine_dir, "r1", **{variable: "grey", unrelated: "INFO"})
    assert counts["stored"] == 0
    line = _said(proc.stderr)
    assert "--config" not in line
    said = line.split(ASKS_FOR, 1)[1]
    assert variable in said and "C3_MATCHER_ENGINES__DIRECTORY" in said, line
    assert unrelated not in said  # a setting that keys no set is not named


@pytest.mark.slow
def test_features_info_given_a_config_prints_its_build_command_with_it(
    held: Path, engine_dir: Path
) -> None:
    proc = run_cli(
        "features", "info", "--config", "grey.toml", "flt", cwd=held.parent, engine_dir=engine_dir
    )
    assert proc.returncode == 0, proc.stderr
    (line,) = [line for line in proc.stderr.splitlines() if "build its set: " in line]
    command = line.split("build its set: ", 1)[1]
    assert command.startswith("c3-matcher --config grey.toml features build flt "), line


def test_the_command_reads_back_as_its_words_and_names_only_the_variables_keying_a_set(
    tmp_path: Path,
) -> None:
    store, config = tmp_path / "my store.mbtiles", Path("my settings.toml")
    env = {
        "C3_MATCHER_MATCHER": '{"photometric": "grey"}',
        "C3_MATCHER_ENGINES__PROVIDERS": '["CPUExecutionProvider"]',
        "C3_MATCHER_LIGHTGLUE__MODE": "adaptive",
        "C3_MATCHER_TRACEBACK": "1",
        "C3_MATCHER_TOOLS_NO_PYPROJ": "1",
        "HOME": "/home/someone",
    }
    built = build_command(store, "xfeat", 448, 32, False, given_settings(config, env))
    command, note = built.line, built.note
    assert str(built) == f"{command} ({note})"
    assert shlex.split(command) == [
        "c3-matcher", "--config", str(config), "features", "build", str(store),
        "--strategy", "xfeat", "--window", "448", "--stride", "32",
    ]  # fmt: skip
    named = note.removeprefix("run it where ").split(" are set", 1)[0].split(", ")
    assert named == ["C3_MATCHER_ENGINES__PROVIDERS", "C3_MATCHER_MATCHER"], note
    alone = build_command(store, "xfeat", 448, 32, False, given_settings(None, {}))
    assert alone.note == "" and str(alone) == alone.line
    assert alone.line == shlex.join(shlex.split(command)[:1] + shlex.split(command)[3:])
