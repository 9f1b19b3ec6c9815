"""Each position error figure says which frames it covers. The run summary (replay's table, the
flight report's headline, ``timing`` in eval.json) covers every matched frame; C3-IT-03's
position figures in eval.json only the matched frames whose true tile is present. A run where a
frame without its true tile still returned a pick shows two different figures: each carries its
frame count and its words, and neither figure changes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from c3_matcher_tools.evaluate import metrics
from c3_matcher_tools.run import FrameOutcome, summarize
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome


def _located(o: FrameOutcome, error_m: float) -> FrameOutcome:
    return dataclasses.replace(o, position_error_m=error_m, est_lat=47.0, est_lon=-99.15)


@pytest.fixture()
def run() -> list[FrameOutcome]:
    """Frame 0 has no true tile among its candidates yet returned a pick (0.128 m off); frames
    1-4 matched their true tile (1, 2, 3 and 10 m off: a mean of 4 m, a median of 2.5 m); frame
    5 raised."""
    return [
        _located(frame_outcome(0, true_present=False), 0.128),
        *(_located(frame_outcome(i), e) for i, e in enumerate((1.0, 2.0, 3.0, 10.0), start=1)),
        frame_outcome(5, status=FrameStatus.INSUFFICIENT),
    ]


def test_each_position_figure_in_the_json_counts_its_frames(run: list[FrameOutcome]) -> None:
    timing = summarize(run).to_json()
    it03 = metrics(run, run).to_json()["C3-IT-03"]
    assert timing["position_error_frames"] == 5  # every matched frame
    assert it03["position_error_frames"] == 4  # matched, true tile present
    assert timing["position_error_m_p50"] == pytest.approx(np.median([0.128, 1, 2, 3, 10]))
    assert it03["median_position_error_m"] == pytest.approx(2.5)
    assert it03["frames_scored"] == 4


def test_replay_says_the_position_figure_covers_every_matched_frame(
    run: list[FrameOutcome],
) -> None:
    from c3_matcher_tools.replay import _report_lines

    report = {"strategy": "xfeat", "wall_s": 1.0, "startup_s": 0.1}
    report |= {"results": "r", "fdr": "f", "geojson": "g", "html": None}
    lines = _report_lines("myflight", report, summarize(run), Path("out"))
    said = next(line for line in lines if "position error" in line)
    assert "p50 2.00, p95 8.60 over every matched frame (5 frames" in said, said
