"""The README's integration-guide snippet runs as written (on the demo data, real engines)."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _snippet() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Using it from Python") :]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "the integration guide has no python block"
    return match.group(1)


@pytest.mark.slow
def test_integration_snippet_runs_as_written(engine_dir: Path, tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    env["C3_MATCHER_ENGINES__DIRECTORY"] = str(engine_dir)
    env["C3_MATCHER_FDR__PATH"] = str(tmp_path / "fdr.jsonl")
    env["C3_MATCHER_MATCHER__MAX_KEYPOINTS"] = "1024"  # keeps the test quick on 2 cores
    proc = subprocess.run(
        [sys.executable, "-c", _snippet()],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    first = proc.stdout.splitlines()[0]  # best tile id, its inlier count, the (I, 4) shape
    found = re.search(r"(\d+) \((\d+), 4\)$", first)
    assert found and found.group(1) == found.group(2), proc.stdout
    assert (tmp_path / "fdr.jsonl").is_file()  # the durable recorder compose_root built


# -- the README is a user's document: true commands, no internal codes, history in docs/ ------
PROCESS_WORDS = re.compile(
    r"\b(?:AZ-\d+|D-C\d|INV-\d|AC-\d+|DECISIONS|issue \d+|seed 00\d|Mode B|Tier-2)\b"
    r"|planning notes|other engineers"
)
DOCS = sorted((REPO / "docs").glob("*.md"))


def _readme() -> str:
    return (REPO / "README.md").read_text(encoding="utf-8")


def test_first_lines_are_the_two_commands_and_they_exist() -> None:
    first = _readme().splitlines()[2:4]
    assert first[0].startswith("- Demo") and first[0].endswith("`scripts/demo`")
    assert first[1].startswith("- Tests") and first[1].endswith("`scripts/test`")
    for script in ("scripts/demo", "scripts/test", "scripts/setup"):
        assert os.access(REPO / script, os.X_OK), script


def test_no_internal_codes_in_the_readme_or_docs() -> None:
    for path in [REPO / "README.md", *DOCS]:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            found = PROCESS_WORDS.search(line)
            assert found is None, f"{path.name}:{number}: {found.group(0)!r}"


def test_readme_is_a_users_document_and_history_lives_in_docs() -> None:
    text = _readme()
    assert len(text.splitlines()) < 600
    for heading in (
        "## Quick start",
        "## Concepts",
        "## Command line",
        "## Configuration",
        "## Using it from Python",
        "## Guarantees",
        "## Credits",
        "## Layout",
    ):
        assert heading in text, heading
    for key in ("c7_inference", "c282_ransac_filter", "c13_fdr"):  # each explained once met
        assert key in text[text.index("## Concepts") : text.index("## Command line")], key
    assert {p.name for p in DOCS} >= {"accuracy.md", "benchmarks.md", "decisions.md"}
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (REPO / link).is_file(), link
    for name in ("accuracy.md", "benchmarks.md", "decisions.md"):  # dated, reproducible
        body = (REPO / "docs" / name).read_text(encoding="utf-8")
        doc = Path(name)
        assert re.search(r"\(20\d\d-\d\d-\d\d\)", body), doc.name
        assert "c3-matcher" in body, doc.name


def test_the_command_table_lists_every_command() -> None:
    from c3_matcher.cli import _build_parser
    from c3_matcher.compose import build_plugin_host

    table = _readme()[_readme().index("## Command line") : _readme().index("## Configuration")]
    parser = _build_parser(build_plugin_host())

    def leaves(p: argparse.ArgumentParser, path: list[str]) -> list[str]:
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            return [" ".join(path)]
        return [leaf for name, sp in subs[0].choices.items() for leaf in leaves(sp, [*path, name])]

    for command in leaves(parser, []):
        assert f"`c3-matcher {command}" in table, command
