"""The command line speaks one dialect: every command's ``--help`` is walked and checked.

- every command and subcommand has a help line, every positional and every option a help text;
- every command that prints a result offers ``--json`` (``match`` always prints JSON);
- one flag name per concept (``--max-keypoints``, never ``--keypoints``);
- nothing a user reads names internal process codes;
- ``--help`` itself works for every command (exit 0, usage on stdout).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from c3_matcher.cli import _build_parser
from c3_matcher.compose import build_plugin_host

EXE = Path(sys.executable).with_name("c3-matcher")

# Commands whose output is a result a program may want to read: each has --json.
PRINTS_A_RESULT = {
    "plugins",
    "config",
    "engines list",
    "engines verify",
    "engines build",
    "engines bench",
    "tiles build",
    "tiles info",
    "tiles digest",
    "dataset render",
    "dataset import",
    "dataset info",
    "replay",
    "eval",
    "bench",
    "features build",
    "features info",
}
ALWAYS_JSON = {"match"}  # its stdout is exactly one JSON object
# A concept has one flag name: the names on the left must not be offered (visibly) anywhere.
SYNONYMS = {"--keypoints": "--max-keypoints", "--json-out": "--json", "--output": "--out"}
# Internal codes a user cannot decode (the spec's C3-IT-0x / C3-PT-01 metric names are fine).
PROCESS_WORDS = re.compile(
    r"\b(?:AZ-\d+|D-C\d|INV-\d|AC-\d+|DECISIONS|issue \d+|seed 00\d|Mode B|Tier-2)\b"
)


def _commands() -> Iterator[tuple[str, argparse.ArgumentParser, str | None]]:
    """(command path, its parser, its help line) for every command and subcommand."""
    parser = _build_parser(build_plugin_host())

    def walk(
        p: argparse.ArgumentParser, path: list[str]
    ) -> Iterator[tuple[str, argparse.ArgumentParser, str | None]]:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                helps = {a.dest: a.help for a in action._choices_actions}
                for name, sub in action.choices.items():
                    yield " ".join([*path, name]), sub, helps.get(name)
                    yield from walk(sub, [*path, name])

    yield "", parser, parser.description
    yield from walk(parser, [])


COMMANDS = {path: (parser, line) for path, parser, line in _commands()}
LEAVES = sorted(
    path
    for path, (parser, _) in COMMANDS.items()
    if path and not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
)


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions if a.help != argparse.SUPPRESS for s in a.option_strings}


def test_the_expected_commands_are_there() -> None:
    assert {"plugins", "config", "engines list", "engines verify", "match"} <= set(LEAVES)
    assert {"tiles build", "dataset import", "dataset info", "replay", "eval", "bench"} <= set(
        LEAVES
    )  # the ground tools are installed in the development environment


@pytest.mark.parametrize("path", sorted(p for p in COMMANDS if p))
def test_every_command_and_argument_has_help(path: str) -> None:
    parser, line = COMMANDS[path]
    assert line and line.strip(), f"`c3-matcher {path}` has no help line"
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction | argparse._HelpAction):
            continue
        if action.help == argparse.SUPPRESS:
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help and action.help.strip(), f"`c3-matcher {path}`: {name} has no help"


@pytest.mark.parametrize("path", sorted(PRINTS_A_RESULT | ALWAYS_JSON))
def test_commands_that_print_a_result_offer_json(path: str) -> None:
    assert path in COMMANDS, f"no command `{path}`"
    parser, _ = COMMANDS[path]
    if path in ALWAYS_JSON:
        assert "--json" not in _options(parser)
    else:
        assert "--json" in _options(parser), f"`c3-matcher {path}` has no --json"


def test_one_flag_name_per_concept() -> None:
    for path in LEAVES:
        offered = _options(COMMANDS[path][0])
        for old, new in SYNONYMS.items():
            assert old not in offered, f"`c3-matcher {path}` offers {old}: the flag is {new}"
    users = [p for p in LEAVES if "--max-keypoints" in _options(COMMANDS[p][0])]
    assert {"match", "replay", "eval", "bench"} <= set(users)


def test_groups_list_their_subcommands() -> None:
    for path, (parser, _) in COMMANDS.items():
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                text = parser.format_help()
                for name in action.choices:
                    assert name in text, f"`c3-matcher {path} --help` does not list {name}"


@pytest.mark.parametrize("path", ["", *sorted(p for p in COMMANDS if p)])
def test_help_runs_and_names_no_process_codes(path: str) -> None:
    proc = subprocess.run(
        [str(EXE), *path.split(), "--help"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: c3-matcher"), proc.stdout[:200]
    found = PROCESS_WORDS.search(proc.stdout)
    assert found is None, f"`c3-matcher {path} --help` says {found.group(0)!r}"


def test_plugins_output_names_no_process_codes() -> None:
    proc = subprocess.run([str(EXE), "plugins"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    found = PROCESS_WORDS.search(proc.stdout)
    assert found is None, f"`c3-matcher plugins` says {found.group(0)!r}"
    assert "disk_lightglue (selected)" in proc.stdout


def test_config_prints_toml_that_reads_back(tmp_path: Path) -> None:
    import json
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    env["C3_MATCHER_MATCHER__MAX_KEYPOINTS"] = "1024"
    text = subprocess.run(
        [str(EXE), "config"], capture_output=True, text=True, env=env, timeout=120
    )
    assert text.returncode == 0, text.stderr
    assert "# RANSAC inliers a candidate needs" in text.stdout  # each setting explained
    found = PROCESS_WORDS.search(text.stdout)
    assert found is None, f"`c3-matcher config` says {found.group(0)!r}"
    saved = tmp_path / "c3.toml"
    saved.write_text(text.stdout)
    env.pop("C3_MATCHER_MATCHER__MAX_KEYPOINTS")
    back = subprocess.run(
        [str(EXE), "--config", str(saved), "config", "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert back.returncode == 0, back.stderr
    assert json.loads(back.stdout)["matcher"]["max_keypoints"] == 1024
