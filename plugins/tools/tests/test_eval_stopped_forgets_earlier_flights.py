"""An eval over several flights into the ``--out`` of an earlier one, stopped during its first
flight, leaves none of the earlier run's flight reports looking like this run's: every flight's
earlier ``eval.json`` and charts are removed before the first flight runs (``sift_magsac``)."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
from collections.abc import Callable
from pathlib import Path

from .test_replay_interrupted import DEMO, _stopped_once_a_frame_is_done

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]


def test_a_stopped_eval_leaves_no_earlier_eval_json_in_the_flights_it_did_not_reach(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    earlier_first = small_flight("naip_demo", where="earlier")  # the demo's name, two frames
    second = small_flight("second", where="second")
    out = tmp_path / "out"
    quick = ("--strategy", "sift_magsac", "--no-baseline", "--determinism-frames", "1")
    earlier = c3("eval", str(earlier_first), str(second), *quick, "--out", str(out))
    assert earlier.returncode == 0, earlier.stderr
    assert (out / "second" / "eval.json").is_file() and (out / "second" / "error.png").is_file()
    first = tmp_path / "demo"  # thirty frames: stopped during it
    shutil.copytree(DEMO, first)
    args = ["eval", str(first), str(second), *quick, "--samples", "0", "--out", str(out)]
    returncode, stderr = _stopped_once_a_frame_is_done(args, signal.SIGTERM, tmp_path)
    assert returncode == 143, stderr
    stopped = json.loads((out / "naip_demo" / "eval.json").read_text())
    assert stopped["complete"] is False and stopped["dataset"] == str(first)
    left = sorted(p.name for p in (out / "second").iterdir())
    assert "eval.json" not in left and "matches" not in left, left
    assert not any(name.endswith(".png") for name in left), left
    summary = json.loads((out / "summary.json").read_text())  # the flight not reached named
    assert [r["flight"] for r in summary] == ["naip_demo", "second"]
    assert summary[0]["stopped"].startswith("stopped after ")
    assert summary[1]["stopped"] == "not run: the evaluation was stopped before this flight"
