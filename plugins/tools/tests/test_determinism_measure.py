"""C3-IT-02 names every frame whose second run differs from its first, by fingerprint or by
status alone, the last frame as well as the others, and eval's table marks the strategy DIFF;
``--determinism-frames N`` runs the first N frames again, no fewer."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from c3_matcher_tools.eval_tables import table_row
from c3_matcher_tools.run import FlightRun, FrameOutcome, StrategyEval, summarize
from c3_matcher_tools.run.acceptance import metrics
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]


def _run() -> list[FrameOutcome]:
    return [frame_outcome(i) for i in range(3)]


def _it02_cell(run1: Sequence[FrameOutcome], run2: Sequence[FrameOutcome]) -> str:
    """The IT-02 cell of eval's table row for a strategy whose runs were ``run1``, ``run2``."""
    row = StrategyEval(
        FlightRun("xfeat", {}, tuple(run1), 0.0, 0.0),
        metrics(run1, run2),
        summarize(run1),
        None,
        None,
    )
    return table_row(row).split()[2]


def test_a_last_frame_whose_fingerprint_differs_is_named_and_marked_diff() -> None:
    run1 = _run()
    run2 = [*run1[:2], replace(run1[2], fingerprint="another")]
    it02 = metrics(run1, run2).determinism
    assert (it02.frames_compared, it02.differing_frames, it02.passed) == (3, (2,), False)
    assert metrics(run1, run2).to_json()["C3-IT-02"]["differing_frames"] == [2]
    assert _it02_cell(run1, run2) == "DIFF"
    assert _it02_cell(run1, run1) == "same"


def test_a_frame_whose_status_alone_differs_is_named() -> None:
    """Frame 1 raised the second time with the same fingerprint: a different result still."""
    run1 = _run()
    run2 = [run1[0], replace(run1[1], status=FrameStatus.INSUFFICIENT), run1[2]]
    assert run2[1].fingerprint == run1[1].fingerprint
    it02 = metrics(run1, run2).determinism
    assert (it02.differing_frames, it02.passed) == ((1,), False)
    assert _it02_cell(run1, run2) == "DIFF"


def test_eval_runs_the_first_n_frames_twice(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    """A two-frame flight with ``--determinism-frames 1``: one frame compared, not none or two."""
    flight, out = small_flight("twice"), tmp_path / "out"
    proc = c3(
        "eval", str(flight), "--strategy", "sift_magsac", "--no-baseline",
        "--determinism-frames", "1", "--samples", "0", "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (entry,) = json.loads((out / "eval.json").read_text())["strategies"]
    assert entry["metrics"]["C3-IT-02"] == {
        "frames_compared": 1,
        "differing_frames": [],
        "pass": True,
    }
