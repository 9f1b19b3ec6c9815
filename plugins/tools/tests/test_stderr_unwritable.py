"""Progress is only shown: a run whose stderr cannot be written (a full log disk, a closed
pipe) finishes and writes its results; the bar (or the line) is lost, the run is not."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from c3_matcher.config_sources import ENV_PREFIX
from c3_matcher_tools.dataset.progress import ProgressBar

from .conftest import C3, DEMO, SmallFlight


class _FullDisk(io.StringIO):
    writes = 0

    def write(self, s: str) -> int:
        self.writes += 1
        raise OSError(28, "No space left on device")


def test_a_stream_that_cannot_be_written_stops_the_bar_not_the_caller() -> None:
    stream = _FullDisk()
    bar = ProgressBar("replay", stream=stream, every=1)
    for done in range(1, 6):
        bar(done, 5)  # raises nothing
    assert stream.writes == 1  # tried once, then left alone


def test_a_closed_stream_stops_the_bar() -> None:
    stream = io.StringIO()
    stream.close()
    ProgressBar("replay", stream=stream)(1, 2)


def _stderr_full(cwd: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``c3-matcher ARGS`` with its stderr on a full disk (``/dev/full``)."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    with open("/dev/full", "w") as full:
        return subprocess.run(
            [sys.executable, "-m", "c3_matcher.cli", *args],
            stdout=subprocess.PIPE,
            stderr=full,
            text=True,
            env={**clean, **env},
            cwd=cwd,
            timeout=600,
        )


def test_replay_with_stderr_on_a_full_disk_writes_its_results(
    tmp_path: Path, small_flight: SmallFlight
) -> None:
    flight = small_flight("stderr_full")
    out = tmp_path / "out"
    done = _stderr_full(
        tmp_path, "replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)
    )
    assert done.returncode == 0, done.stdout
    assert "replay stderr_full with sift_magsac: 2 frames" in done.stdout
    lines = (out / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == [0, 1]


def test_features_build_with_stderr_on_a_full_disk_builds_the_set(
    tmp_path: Path, engine_dir: Path
) -> None:
    store = tmp_path / "store.mbtiles"
    shutil.copyfile(DEMO / "tiles.mbtiles", store)
    done = _stderr_full(
        tmp_path,
        *("features", "build", str(store), "--strategy", "xfeat", "--workers", "0"),
        C3_MATCHER_ENGINES__DIRECTORY=str(engine_dir),
    )
    assert done.returncode == 0, done.stdout
    assert "xfeat: 35 extracted" in done.stdout


def test_an_out_folder_that_cannot_be_made_is_named_with_its_option_and_reason(
    c3: C3, small_flight: SmallFlight
) -> None:
    flight = small_flight("bad_out")
    done = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", "/proc/no/such")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        "c3-matcher: --out: /proc/no/such: cannot be made: No such file or directory"
    )


def test_the_failure_line_lost_to_a_full_stderr_leaves_the_exit_status(
    tmp_path: Path, small_flight: SmallFlight
) -> None:
    flight = small_flight("bad_out_full")
    done = _stderr_full(tmp_path, "replay", str(flight), "--out", "/proc/no/such")
    assert done.returncode == 2
