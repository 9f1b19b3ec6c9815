"""On a flight computer's install (the airborne profile: strict, no ground tools) the command
line sends nobody to a command it does not have: a ground command (``replay``, ``tiles``,
``engines build``...) is refused in one line saying it comes with the ground tools, and a
missing engine says where engines come from there (a ground machine's build, copied over),
besides the build command of a ground install.

The airborne install is the real airborne profile (the generated ``buildflags/airborne``) over
the plugins installed here: strict, it leaves the ground tools' plugin out, as on the aircraft."""

from __future__ import annotations

import os
import runpy
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.plugins import PluginHost
from c3_matcher.plugins.manager import discover
from c3_matcher.profiles import BuildProfile

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "demo"
AIRBORNE = REPO / "buildflags" / "airborne" / "src" / "c3_matcher_profile_airborne"
TOOLS = "c3-matcher-tools"


def _airborne_host() -> PluginHost:
    data = runpy.run_path(str(AIRBORNE / "__init__.py"))["PROFILE"]
    return PluginHost(BuildProfile.from_data(data, "c3-matcher-profile-airborne"), discover())


@pytest.fixture
def airborne(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> PluginHost:
    """The command line of an airborne install; no ``C3_MATCHER_`` variable of the caller's,
    the FDR in ``tmp_path``."""
    import c3_matcher.compose

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    host = _airborne_host()
    assert TOOLS in {p.distribution for p in host.ignored}  # installed here, left out there
    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", lambda: host)
    return host


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["replay", "myflight", "--out", "o"], "replay"),
        (["tiles", "build", "ortho.tif", "tiles.mbtiles"], "tiles"),
        (["dataset", "import"], "dataset"),
        (["eval", "myflight"], "eval"),
        (["bench"], "bench"),
        (["features", "info", "tiles.mbtiles"], "features"),
        (["engines", "build", "--only", "disk/depth"], "engines build"),
        (["--config", "c3.toml", "engines", "bench"], "engines bench"),
    ],
)
def test_a_ground_command_is_refused_saying_it_comes_with_the_ground_tools(
    airborne: PluginHost, capsys: pytest.CaptureFixture[str], argv: list[str], command: str
) -> None:
    assert main(argv) == 2
    said = capsys.readouterr()
    lines = said.err.strip().splitlines()
    assert len(lines) == 1 and said.out == "", said
    assert f"`c3-matcher {command}`" in lines[0] and "ground tools" in lines[0]
    assert f"pip install {TOOLS}" in lines[0] and "invalid choice" not in lines[0]
    assert "[engines] directory" in lines[0]  # what a flight computer does instead


def test_a_name_no_build_has_is_still_argparses_refusal(
    airborne: PluginHost, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["replays", "myflight"])
    assert exited.value.code == 2
    assert "invalid choice: 'replays'" in capsys.readouterr().err


def test_a_ground_install_runs_its_ground_commands(capsys: pytest.CaptureFixture[str]) -> None:
    """Where the tools are installed, ``engines build`` is theirs: its help, not the refusal."""
    with pytest.raises(SystemExit) as exited:
        main(["engines", "build", "--help"])
    assert exited.value.code == 0
    assert "--only" in capsys.readouterr().out


def test_a_missing_engine_says_engines_come_from_a_ground_machine(
    airborne: PluginHost,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    empty = tmp_path / "engines"
    empty.mkdir()
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(empty))
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")]
    assert main([*argv, "--tile-gsd", "0.0968"]) == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "no valid disk/depth engine" in line, line
    assert "build it with `c3-matcher engines build --only disk/depth`" in line
    assert f"the ground tools, {TOOLS}" in line
    assert f"or copy the engines a ground machine built into {empty}" in line


def _commands(parser: object, prefix: str = "") -> set[str]:
    """Every command and group subcommand of ``parser`` by its full name."""
    from c3_matcher.ground_commands import _subcommands

    found: set[str] = set()
    for name, sub in _subcommands(parser).items():  # type: ignore[arg-type]
        found.add(prefix + name)
        found |= _commands(sub, f"{prefix}{name} ")
    return found


def test_the_ground_commands_named_are_those_the_ground_tools_add() -> None:
    """The list the refusal reads is the tools' commands, neither more nor fewer: the commands
    this full install has that the airborne build has not (a group's subcommands counted under
    their group when the group itself is the tools')."""
    from c3_matcher.cli import _build_parser
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.ground_commands import GROUND_COMMANDS

    full, airborne = (
        _commands(_build_parser(build_plugin_host())),
        _commands(_build_parser(_airborne_host())),
    )
    added = full - airborne
    tops = {name for name in added if " " not in name or name.split()[0] in airborne}
    tops = {name for name in tops if not any(name.startswith(f"{t} ") for t in tops - {name})}
    assert tops == set(GROUND_COMMANDS)
