"""A long ``replay`` or ``eval`` killed outright (SIGKILL, out of memory, power cut), with no
chance to write its ``results.jsonl``, keeps the frames it flew: each frame's line is appended
to ``results.jsonl.partial`` as it is flown, in the format of ``results.jsonl``; a run that
ends writes ``results.jsonl`` as before and leaves no partial file (the ``sift_magsac``
baseline on the demo flight)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from c3_matcher.compose import build_plugin_host
from c3_matcher.config import C3Settings
from c3_matcher.config_sources import ENV_PREFIX
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import FlightOptions, flight_report, fly, write_flight_outputs
from c3_matcher_tools.run.feature_sources import FDR_LOG
from c3_matcher_tools.run.forget import forget_strategies
from c3_matcher_tools.run.records import FrameOutcome
from c3_matcher_tools.run.run_mark import RUN_MARK
from c3_matcher_tools.testing.cli import run_cli

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"
PARTIAL = "results.jsonl.partial"
SmallFlight = Callable[..., Path]  # the fixture of conftest.py
_VARYING = ("elapsed_ms", "matched_at")
"""What differs between two runs of the same frames: the time each took and was matched at."""


def _killed_once_frames_are_kept(args: Sequence[str], partial: Path, frames: int = 2) -> None:
    """``c3-matcher ARGS`` (without the caller's settings) killed with SIGKILL once ``partial``
    holds ``frames`` whole lines."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(ENV_PREFIX)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "c3_matcher.cli", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    try:
        deadline = time.monotonic() + 300
        while not partial.is_file() or partial.read_bytes().count(b"\n") < frames:
            assert proc.poll() is None, f"the run ended with no {frames} frames in {partial}"
            assert time.monotonic() < deadline, f"no {frames} frames in {partial} in 300 s"
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=60) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _steady(line: dict[str, Any]) -> dict[str, Any]:
    """``line`` of results without what differs from run to run (:data:`_VARYING`), however
    deep; its keys kept in order."""
    return {
        k: _steady(v) if isinstance(v, dict) else v for k, v in line.items() if k not in _VARYING
    }


def _kept_lines(partial: Path) -> list[dict[str, Any]]:
    """The lines of a killed run's ``partial``, each whole and parsed, of frames 0, 1, ..."""
    text = partial.read_text()
    assert text.endswith("\n")
    lines = [json.loads(line) for line in text.splitlines()]
    assert [line["index"] for line in lines] == list(range(len(lines)))
    return lines


def test_a_replay_killed_outright_keeps_the_frames_it_flew(tmp_path: Path) -> None:
    flight, out = shutil.copytree(DEMO, tmp_path / "flight"), tmp_path / "out"
    args = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)]
    _killed_once_frames_are_kept(args, out / PARTIAL)
    assert not (out / "results.jsonl").exists()
    assert json.loads((out / RUN_MARK).read_text())["running"] is True  # marked unfinished
    kept = _kept_lines(out / PARTIAL)
    assert 2 <= len(kept) < 30
    again = tmp_path / "again"  # the same frames flown to the end: the same lines
    done = run_cli(*args[:-1], again, "--limit", str(len(kept)), cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr
    whole = [json.loads(line) for line in (again / "results.jsonl").read_text().splitlines()]
    assert [_steady(line) for line in kept] == [_steady(line) for line in whole]
    assert [list(line) for line in kept] == [list(line) for line in whole]
    assert not (again / PARTIAL).exists()
    rerun = run_cli(*args, "--limit", "1", cwd=tmp_path, timeout=600)  # into the killed one's
    assert rerun.returncode == 0, rerun.stderr
    assert not (out / PARTIAL).exists()
    assert len((out / "results.jsonl").read_text().splitlines()) == 1


def test_an_eval_killed_outright_keeps_the_frames_of_the_strategy_it_flew(
    tmp_path: Path,
) -> None:
    flight, out = shutil.copytree(DEMO, tmp_path / "flight"), tmp_path / "out"
    args = ["eval", str(flight), "--strategy", "sift_magsac", "--samples", "0", "--out", str(out)]
    _killed_once_frames_are_kept(args, out / "sift_magsac" / PARTIAL)
    assert json.loads((out / RUN_MARK).read_text())["running"] is True
    assert 2 <= len(_kept_lines(out / "sift_magsac" / PARTIAL)) < 30
    assert not (out / "sift_magsac" / "results.jsonl").exists()


def test_an_eval_that_ends_leaves_no_partial_file(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    """Neither in the strategy's directory nor in its second run's, which keeps no frames."""
    flight, out = small_flight("two_frames"), tmp_path / "out"
    args = ["eval", flight, "--strategy", "sift_magsac", "--samples", "0", "--out", out]
    done = run_cli(*args, cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stderr
    assert (out / "sift_magsac" / "results.jsonl").is_file()
    assert (out / "sift_magsac" / "run2").is_dir()
    assert sorted(out.rglob(f"*{PARTIAL}")) == []


def _as_before(outcomes: Sequence[FrameOutcome]) -> bytes:
    """What ``results.jsonl`` held for ``outcomes`` before frames were kept as flown."""
    return "".join(json.dumps(o.to_json()) + "\n" for o in outcomes).encode()


def test_each_frame_is_kept_as_flown_and_a_run_that_ends_writes_its_results_as_before(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    """After each frame the partial file holds exactly the lines ``results.jsonl`` will hold
    for the frames done; once the run's files are written it is gone, and ``results.jsonl`` is
    byte for byte what it was before."""
    dataset, out = load_dataset(small_flight("two_frames")), tmp_path / "out"
    seen: list[bytes] = []

    def progress(done: int, planned: int) -> None:
        seen.append((out / PARTIAL).read_bytes())

    options = FlightOptions(progress=progress, keep_stopped=True)
    host = build_plugin_host()
    run = fly(C3Settings(), "sift_magsac", dataset, out, plugin_host=host, options=options)
    assert len(run.outcomes) == 2
    assert seen == [_as_before(run.outcomes[:n]) for n in (1, 2)]
    write_flight_outputs(out, dataset, run, flight_report(dataset, run), say_no_report=False)
    assert not (out / PARTIAL).exists()
    assert (out / "results.jsonl").read_bytes() == _as_before(run.outcomes) == seen[-1]


def test_a_flight_whose_frames_are_not_kept_writes_no_partial_file(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    """eval's second run: no partial file, and an earlier one there is removed (it is no
    result of this run's)."""
    dataset, out = load_dataset(small_flight("two_frames")), tmp_path / "out"
    out.mkdir()
    (out / PARTIAL).write_text("an earlier run's\n")
    run = fly(C3Settings(), "sift_magsac", dataset, out, plugin_host=build_plugin_host())
    assert len(run.outcomes) == 2
    assert not (out / PARTIAL).exists()


def test_forgetting_a_strategy_removes_the_frames_a_killed_run_kept(tmp_path: Path) -> None:
    """A rerun of fewer strategies forgets an earlier killed one's directory whole."""
    killed = tmp_path / "sift_magsac"
    killed.mkdir()
    for name in (FDR_LOG, "matcher.log", PARTIAL):
        (killed / name).write_text("{}\n")
    forget_strategies(tmp_path, ["sift_magsac"], log=FDR_LOG)
    assert not killed.exists()
