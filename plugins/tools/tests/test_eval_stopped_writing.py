"""An ``eval`` stopped by Ctrl-C while it writes a finished strategy's files keeps that
strategy's figures in ``eval.json`` and names only the files it did not write; a stopped eval
leaves no earlier eval's results in the directories of the strategies it never reached (the
``sift_magsac`` baseline on a two-frame flight, a real SIGINT)."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.cli import main

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
QUICK = ("--determinism-frames", "1", "--samples", "0")


def _interrupted_as_the_map_is_written(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C (a real SIGINT to this process) as a run's ``flight.geojson`` is to be written."""
    import c3_matcher_tools.geojson

    def interrupted(*args: object, **kwargs: object) -> Path:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the signal did not stop the run")

    monkeypatch.setattr(c3_matcher_tools.geojson, "write_geojson", interrupted)


def test_ctrl_c_while_a_finished_strategys_files_are_written_keeps_its_figures(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    flight = small_flight("two_frames")
    out = tmp_path / "out"
    _interrupted_as_the_map_is_written(monkeypatch)
    args = ["eval", str(flight), "--strategy", "sift_magsac", "--no-baseline", "--out", str(out)]
    assert main([*args, *QUICK]) == 130
    report = json.loads((out / "eval.json").read_text())
    assert report["complete"] is False and report["not_run"] == []
    (entry,) = report["strategies"]
    assert entry["metrics"]["C3-IT-04"]["frames"] == 2, entry  # its figures, whole
    assert len(entry["per_frame"]) == 2
    assert entry["geojson"] is None and entry["html"] is None
    assert entry["stopped"].startswith("stopped while its files were written: flight.geojson")
    results = (out / "sift_magsac" / "results.jsonl").read_text().splitlines()
    assert len(results) == 2
    assert not (out / "sift_magsac" / "flight.geojson").exists()
    err = capsys.readouterr().err
    assert "interrupted during sift_magsac on two_frames" in err, err


def test_a_stopped_eval_leaves_no_earlier_results_of_strategies_it_did_not_reach(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import c3_matcher_tools.evaluate

    flight = small_flight("two_frames")
    out = tmp_path / "out"
    both = ["eval", str(flight), "--strategy", "sift_magsac", "--out", str(out), *QUICK]
    assert main(both) == 0  # sift_magsac, then the baseline (itself): one strategy
    earlier = out / "sift_magsac"
    assert (earlier / "results.jsonl").is_file()
    (earlier / "notes.txt").write_text("the user's\n")

    def stopped(*args: object, **kwargs: object) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the signal did not stop the run")

    monkeypatch.setattr(c3_matcher_tools.evaluate, "evaluate_strategy", stopped)
    assert main(both) == 130
    report = json.loads((out / "eval.json").read_text())
    assert report["complete"] is False
    assert sorted(p.name for p in earlier.iterdir()) == ["notes.txt"]  # the user's file stays
