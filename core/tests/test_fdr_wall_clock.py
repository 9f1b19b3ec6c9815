"""``c3-matcher fdr`` of a log whose wall clock went back between records (a restart on a
computer whose clock was not set): the span printed is the earliest to the latest time, and the
step back is said (it printed "2026-... to 1970-...")."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.fdr.check import check_fdr

WALLS = (
    "2026-12-04T19:52:55.000000+00:00",
    "2026-12-04T19:52:56.000000+00:00",
    "1970-01-01T00:00:05.000000+00:00",
    "1970-01-01T00:00:06.000000+00:00",
)


def _log(path: Path) -> Path:
    lines = [
        json.dumps(
            {"seq": n, "kind": "t", "recorded_at_ns": n, "wall_time": wall, "payload": {}},
            separators=(",", ":"),
        )
        for n, wall in enumerate(WALLS, start=1)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_span_is_earliest_to_latest_and_the_step_back_counted(tmp_path: Path) -> None:
    check = check_fdr(_log(tmp_path / "fdr.jsonl"))
    assert check.wall_times == ("1970-01-01T00:00:05+00:00", "2026-12-04T19:52:56+00:00")
    assert check.wall_went_back == 1
    assert check.intact  # seq order is the log's order: the clock does not damage it


def test_the_command_says_the_clock_went_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["fdr", str(_log(tmp_path / "fdr.jsonl"))]) == 0
    said = capsys.readouterr().out
    assert "1970-01-01T00:00:05+00:00 to 2026-12-04T19:52:56+00:00" in said, said
    assert "wall clock went back 1 time(s)" in said, said
