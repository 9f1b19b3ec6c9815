"""A ``replay`` stopped while it writes its files says, on stdout and in ``report.json``, only
the files it wrote; one stopped before its first frame is done says that nothing was scored,
not that the flight has no ground truth (the ``sift_magsac`` baseline, a real SIGINT)."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py


def _interrupt(*args: object, **kwargs: object) -> None:
    """Ctrl-C: a real SIGINT to this process, which the run's handler turns into a stop."""
    os.kill(os.getpid(), signal.SIGINT)
    raise AssertionError("the signal did not stop the run")


def test_a_replay_stopped_after_its_map_names_the_map_and_no_flight_report(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import c3_matcher_tools.run.outputs

    monkeypatch.setattr(c3_matcher_tools.run.outputs, "write_html_report", _interrupt)
    flight, out = small_flight("two_frames"), tmp_path / "out"
    args = ["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--json"]
    assert main(args) == 130
    printed = json.loads(capsys.readouterr().out)
    saved = json.loads((out / "report.json").read_text())
    for report in (printed, saved):
        assert report["geojson"] == str(out / "flight.geojson")
        assert report["html"] is None
        assert report["frames_done"] == 2
    assert (out / "flight.geojson").is_file() and not (out / "report.html").exists()
    assert "running" not in json.loads((out / RUN_MARK).read_text())


def test_a_replay_stopped_before_its_first_frame_says_nothing_was_scored(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import c3_matcher_tools.run.flight

    monkeypatch.setattr(c3_matcher_tools.run.flight, "_fly_frame", _interrupt)
    flight, out = small_flight("two_frames"), tmp_path / "out"
    assert main(["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)]) == 130
    said = capsys.readouterr().out
    assert "no frame done: nothing scored" in said, said
    assert "no ground truth" not in said
