"""A replay whose stdout cannot be written (its reader gone, a full disk under it) still writes
every file of the run, then fails as it would have; one whose files cannot be written still
leaves the report on stdout (two-frame flights, the ``sift_magsac`` baseline)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import IO

import pytest

from c3_matcher.config_sources import ENV_PREFIX
from c3_matcher_tools.run.run_mark import RUN_MARK

from .conftest import C3, SmallFlight


def _replay(
    cwd: Path, flight: Path, out: Path, stdout: IO[str] | int, *more: str
) -> tuple[int, str]:
    """``c3-matcher replay FLIGHT --out OUT MORE`` with its stdout on ``stdout``: the exit
    status and stderr."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    argv = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), *more]
    done = subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", *argv],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        env=clean,
        cwd=cwd,
        timeout=600,
    )
    return done.returncode, done.stderr


def _assert_whole_run(out: Path) -> None:
    """Every file of a replay that went through, its ``run.json`` saying it is whole."""
    lines = (out / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == [0, 1]
    report = json.loads((out / "report.json").read_text())
    assert report["frames_done"] == 2 and report["geojson"] == str(out / "flight.geojson")
    assert (out / "flight.geojson").is_file()
    assert json.loads((out / RUN_MARK).read_text()).get("complete", True) is True


@pytest.mark.parametrize("as_json", [False, True])
def test_a_replay_to_a_full_stdout_writes_its_files_and_exits_1_naming_stdout(
    tmp_path: Path, small_flight: SmallFlight, as_json: bool
) -> None:
    flight, out = small_flight("stdout_full"), tmp_path / "out"
    with open("/dev/full", "w") as full:
        status, err = _replay(tmp_path, flight, out, full, *(["--json"] if as_json else []))
    assert status == 1, err
    assert "c3-matcher: cannot write the result to stdout: No space left on device" in err, err
    _assert_whole_run(out)


def test_a_replay_whose_reader_is_gone_writes_its_files_and_exits_141(
    tmp_path: Path, small_flight: SmallFlight
) -> None:
    flight, out = small_flight("reader_gone"), tmp_path / "out"
    read, write = os.pipe()
    os.close(read)  # the reader stopped before the report
    try:
        status, err = _replay(tmp_path, flight, out, write)
    finally:
        os.close(write)
    assert status == 141, err
    _assert_whole_run(out)


def test_a_replay_whose_files_cannot_be_written_still_prints_its_report(
    tmp_path: Path, small_flight: SmallFlight, c3: C3
) -> None:
    flight, out = small_flight("disk_full"), tmp_path / "out"
    ran = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert ran.returncode == 0 and len((out / "results.jsonl").read_bytes()) > 4096
    again = c3(
        "replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), limit_file_bytes=4096
    )
    assert again.returncode != 0 and "File too large" in again.stderr, again.stderr
    assert "replay disk_full with sift_magsac: 2 frames" in again.stdout, again.stdout
