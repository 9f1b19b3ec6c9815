"""eval's inliers.png draws a frame that raised at the inlier count it fell short with, beside
C3-IT-01's bar; C3-IT-01 counts that frame as 0 inliers. The chart marks such a frame apart and
its legend says so; a matched frame at the same count is drawn as before."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher_tools import plots
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import FlightRun
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
RAISED = 2


def _run(raised: bool) -> FlightRun:
    """Five frames with 100 inliers, frame 2 with 59: raised (below the threshold), or not."""
    outcomes = [frame_outcome(i) for i in range(5)]
    short = frame_outcome(RAISED, status=FrameStatus.INSUFFICIENT)
    outcomes[RAISED] = (
        dataclasses.replace(short, insufficient_best=59)
        if raised
        else frame_outcome(RAISED, inliers=59)
    )
    return FlightRun("xfeat", {}, tuple(outcomes), 0.0, 0.0)


def _chart(tmp_path: Path, raised: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[Any, str]:
    """(inliers.png's pixels, every text written on it)."""
    written: list[str] = []
    put_text = cv2.putText

    def record(canvas: Any, text: str, *args: Any) -> Any:
        written.append(text)
        return put_text(canvas, text, *args)

    monkeypatch.setattr(plots.cv2, "putText", record)
    out = tmp_path / ("raised" if raised else "matched")
    plots.eval_plots(load_dataset(DEMO), [_run(raised)], out, samples=0)
    monkeypatch.undo()
    image = cv2.imread(str(out / "inliers.png"))
    assert image is not None
    return image, " ".join(written)


def test_a_frame_that_raised_is_marked_as_counting_zero_in_it01(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    raised, raised_text = _chart(tmp_path, True, monkeypatch)
    matched, matched_text = _chart(tmp_path, False, monkeypatch)
    assert "C3-IT-01" in raised_text and "C3-IT-01" not in matched_text
    differ = np.argwhere((raised != matched).any(axis=2))
    assert differ.size, "the raised frame is drawn as a matched one"
    # the chart's layout: the plot spans x 70..730 of 900 px, five frames at 165 px apart
    frame_x = 70 + (900 - 70 - 170) * RAISED / 4
    in_plot = differ[differ[:, 1] < 900 - 170]
    assert in_plot.size and np.abs(in_plot[:, 1] - frame_x).max() <= 8
