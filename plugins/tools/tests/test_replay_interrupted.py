"""A long ``c3-matcher replay`` or ``eval`` that is stopped keeps what it did: Ctrl-C (SIGINT)
or SIGTERM during the frames leaves ``results.jsonl`` of the frames done (whole lines), a mark
saying the run is incomplete (replay's ``run.json``, eval's ``eval.json``), exit 130/143 and one
line naming what is kept; a final write that fails (a full disk) still prints the summary of the
frames matched (the ``sift_magsac`` baseline)."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.config_sources import ENV_PREFIX
from c3_matcher_tools.run.run_mark import RUN_MARK

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"
SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]


def _flight(where: Path) -> Path:
    """The demo flight: 30 frames, far more than are done once the first one is."""
    shutil.copytree(DEMO, where)
    return where


def _stopped_once_a_frame_is_done(
    args: list[str], signum: int, where: Path, bar: bytes = rb"\] +[1-9][0-9]*/30 "
) -> tuple[int, str]:
    """``c3-matcher ARGS`` (without the caller's settings) sent ``signum`` once its progress
    bar on stderr counts a frame of 30 done (``bar``): its exit status and its stderr."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    err = where / "stderr"
    with err.open("wb") as sink:
        proc = subprocess.Popen(
            [sys.executable, "-m", "c3_matcher.cli", *args],
            stdout=subprocess.DEVNULL,
            stderr=sink,
            env=env,
            cwd=where,
        )
        try:
            deadline = time.monotonic() + 300
            while re.search(bar, err.read_bytes()) is None:
                assert proc.poll() is None, "the command ended before its first frame was done"
                assert time.monotonic() < deadline, "no frame done in 300 s"
                time.sleep(0.01)
            proc.send_signal(signum)
            return proc.wait(timeout=300), err.read_text()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
    ids=["ctrl-c", "sigterm"],
)
def test_a_stopped_replay_keeps_the_results_of_the_frames_it_did(
    c3: C3, tmp_path: Path, signum: int, code: int, word: str
) -> None:
    flight, out = _flight(tmp_path / "flight"), tmp_path / "out"
    earlier = c3(
        "replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--limit", "1"
    )
    assert earlier.returncode == 0, earlier.stderr
    args = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)]
    returncode, stderr = _stopped_once_a_frame_is_done(args, signum, tmp_path)
    assert returncode == code, stderr
    last = stderr.splitlines()[-1]
    lines = (out / "results.jsonl").read_text().splitlines()
    done = len(lines)
    assert 1 <= done < 30
    assert [json.loads(line)["index"] for line in lines] == list(range(done))
    assert last == (
        f"c3-matcher: {word} after {done} of 30 frames: their results are in "
        f"{out / 'results.jsonl'} ({RUN_MARK} marks the run incomplete)"
    ), last
    mark = json.loads((out / RUN_MARK).read_text())
    assert mark == {
        "command": "c3-matcher replay",
        "dataset": str(flight.resolve()),
        "name": "naip_demo",
        "strategy": "sift_magsac",
        "complete": False,
        "frames_done": done,
        "frames_planned": 30,
    }
    report = json.loads((out / "report.json").read_text())
    assert (report["complete"], report["frames_done"], report["frames_planned"]) == (
        False,
        done,
        30,
    )
    assert report["frames"] == report["ok"] + report["insufficient"] == done  # counts agree
    assert not (out / "flight.geojson").exists() and not (out / "report.html").exists()
    again = c3(
        "replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--limit", "1"
    )
    assert again.returncode == 0, again.stderr  # a whole run there again: marked whole
    assert json.loads((out / RUN_MARK).read_text()) == {
        "command": "c3-matcher replay",
        "dataset": str(flight.resolve()),
        "name": "naip_demo",
        "strategy": "sift_magsac",
    }
    assert json.loads((out / "report.json").read_text())["complete"] is True


def test_a_replay_whose_results_cannot_be_written_still_prints_its_summary(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    proc = c3(
        "replay", str(flight), "--strategy", "sift_magsac", "--out", str(out),
        limit_file_bytes=8 << 10,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout.startswith("replay two_frames with sift_magsac: 2 frames in "), proc.stdout
    assert "  ok 1, insufficient inliers 1" in proc.stdout, proc.stdout
    assert proc.stderr.splitlines()[-1].startswith(f"c3-matcher: {out / 'results.jsonl'}: ")


def test_a_replay_stopped_while_writing_its_files_keeps_every_frame(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C after the last frame, as the map and flight report are written: the frames'
    results are kept all the same, the report printed, and the one line says so (exit 130)."""
    import c3_matcher_tools.replay
    from c3_matcher.cli import main

    def ctrl_c(*args: object, **kwargs: object) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5)  # the signal arrives first

    monkeypatch.setattr(c3_matcher_tools.replay, "write_flight_outputs", ctrl_c)
    flight, out = small_flight("writing"), tmp_path / "out"
    code = main(["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--json"])
    said = capsys.readouterr()
    assert code == 130
    assert said.err.splitlines()[-1] == (
        f"c3-matcher: interrupted after 2 of 2 frames: their results are in {out / 'results.jsonl'}"
    )
    assert json.loads(said.out)["frames_done"] == 2
    lines = (out / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == [0, 1]
    mark = json.loads((out / RUN_MARK).read_text())
    assert (mark["complete"], mark["frames_done"], mark["frames_planned"]) == (True, 2, 2)


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
    ids=["ctrl-c", "sigterm"],
)
def test_a_stopped_eval_keeps_the_flights_finished_and_the_frames_done(
    small_flight: SmallFlight, tmp_path: Path, signum: int, code: int, word: str
) -> None:
    """Two flights; stopped during the second: the first one's figures stay whole, the
    second's ``eval.json`` says it is incomplete, keeps the frames done and names what did not
    run; ``summary.json`` has both rows."""
    first, second = small_flight("two_frames"), _flight(tmp_path / "demo")
    out = tmp_path / "out"
    args = ["eval", str(first), str(second), "--strategy", "sift_magsac", "--samples", "0"]
    returncode, stderr = _stopped_once_a_frame_is_done([*args, "--out", str(out)], signum, tmp_path)
    assert returncode == code, stderr
    report = out / "naip_demo" / "eval.json"
    assert stderr.splitlines()[-1] == (
        f"c3-matcher: {word} during sift_magsac on naip_demo: {report} holds the strategies "
        "that finished and names those not run"
    )
    whole = json.loads((out / "two_frames" / "eval.json").read_text())
    assert whole["complete"] is True and "metrics" in whole["strategies"][0]
    stopped = json.loads(report.read_text())
    assert (stopped["complete"], stopped["not_run"]) == (False, [])
    (row,) = stopped["strategies"]
    results = out / "naip_demo" / "sift_magsac" / "results.jsonl"
    assert (row["frames_planned"], row["results"]) == (30, str(results))
    lines = results.read_text().splitlines()
    assert 1 <= row["frames_done"] == len(lines) < 30
    assert [json.loads(line)["index"] for line in lines] == list(range(len(lines)))
    summary = json.loads((out / "summary.json").read_text())
    assert [(r["flight"], "stopped" in r) for r in summary] == [
        ("two_frames", False),
        ("naip_demo", True),
    ]


def test_an_eval_stopped_in_its_second_run_keeps_its_first(tmp_path: Path) -> None:
    """The determinism run stopped: the first run, whole, is kept and said to be."""
    flight, out = _flight(tmp_path / "demo"), tmp_path / "out"
    args = ["eval", str(flight), "--strategy", "sift_magsac", "--samples", "0", "--out", str(out)]
    run2 = rb"run 2 \[[#.]*\] +[1-9][0-9]*/30 "
    returncode, stderr = _stopped_once_a_frame_is_done(args, signal.SIGINT, tmp_path, run2)
    assert returncode == 130, stderr
    (row,) = json.loads((out / "eval.json").read_text())["strategies"]
    assert (row["frames_done"], row["frames_planned"]) == (30, 30)
    assert row["stopped"].startswith("stopped in its second (determinism) run; its first, of 30")
    lines = (out / "sift_magsac" / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == list(range(30))
