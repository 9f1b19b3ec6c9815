"""The flight report judges a pick as eval does: a pick of another tile whose inliers still place
the frame right (eval's ``right_fix_other_tile``) is marked "O" (another tile, right fix) in the
frames table, over the per-frame chart and on the trajectory, never "W", which is kept for the
picks eval counts false-confident: another tile placed wrong, or the true tile placed wrong (its
inliers over the wrong-fix distance from the ground truth), its true tile there or not. Its
headline position error says which frames it covers. The shipped demo flight, outcomes set per
frame (no engine run here)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.evaluate import metrics
from c3_matcher_tools.run import FrameOutcome, truth_position
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome
from c3_matcher_tools.testing.report import drawn_report

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"


def _placed(dataset: FlightDataset, o: FrameOutcome, error_m: float) -> FrameOutcome:
    """``o`` located ``error_m`` north of where its frame truly looks."""
    truth = truth_position(dataset, dataset.frames[o.index])
    assert truth is not None
    lat, lon = truth
    return dataclasses.replace(
        o,
        truth_lat=lat,
        truth_lon=lon,
        est_lat=lat + error_m / 111_320.0,
        est_lon=lon,
        position_error_m=error_m,
    )


def _outcomes(dataset: FlightDataset) -> list[FrameOutcome]:
    """0: the true tile; 1: another tile, placed right (3 px); 2: another tile, placed wrong
    (300 px); 3: raised with its true tile there; 4: raised without it; 5: the true tile, its
    inliers 40 px off; 6: a pick without its true tile among the candidates, placed wrong."""
    return [
        _placed(dataset, frame_outcome(0), 1.0),
        _placed(dataset, frame_outcome(1, correct=False, error_px=3.0), 2.0),
        _placed(dataset, frame_outcome(2, correct=False, error_px=300.0), 400.0),
        frame_outcome(3, status=FrameStatus.INSUFFICIENT),
        frame_outcome(4, status=FrameStatus.INSUFFICIENT, true_present=False),
        _placed(dataset, frame_outcome(5, error_px=40.0), 50.0),
        _placed(
            dataset, frame_outcome(6, correct=False, true_present=False, error_px=250.0), 300.0
        ),
    ]


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, list[Any]]:
    """(report.html text, the matplotlib figures it embeds, in order)."""
    dataset = load_dataset(DEMO)
    return drawn_report(tmp_path_factory.mktemp("report"), dataset, _outcomes(dataset))


def test_eval_counts_frame_1_as_a_right_fix_on_another_tile_and_2_5_6_as_wrong() -> None:
    outcomes = _outcomes(load_dataset(DEMO))
    fc = metrics(outcomes, []).false_confident
    assert fc.right_fix_other_tile == (1,) and fc.frames == (2, 5, 6)


def test_the_frames_table_marks_a_right_fix_on_another_tile_apart(
    drawn: tuple[str, list[Any]],
) -> None:
    text, _ = drawn
    rows = re.findall(r"<tr><td>(\d+)</td><td>(\w+)</td><td>\d+</td><td>([^<]*)</td>", text)
    verdicts = {int(i): v for i, _, v in rows}
    assert verdicts == {
        0: "true tile",
        1: "O another tile, right fix",
        2: "W wrong tile",
        3: "F failed",
        4: "R rightly raised (true tile absent)",
        5: "W true tile, placed wrong",
        6: "W wrong tile (true tile absent)",
    }
    assert "O: another tile, right fix" in text  # the page's words for the chart's marks


def test_the_per_frame_chart_marks_and_names_it(drawn: tuple[str, list[Any]]) -> None:
    _, figures = drawn
    inliers = figures[1].axes[0]
    marks = {round(t.get_position()[0]): t.get_text() for t in inliers.texts}
    assert marks == {1: "O", 2: "W", 3: "F", 4: "R", 5: "W", 6: "W"}
    legend = [t.get_text() for t in inliers.get_legend().get_texts()]
    assert "O: another tile, right fix" in legend
    assert "W: wrong tile, or true tile, placed wrong" in legend


def test_the_trajectory_marks_the_wrong_fixes_and_the_right_one_apart(
    drawn: tuple[str, list[Any]],
) -> None:
    _, figures = drawn
    trajectory = figures[0].axes[0]
    marked = {c.get_label(): len(c.get_offsets()) for c in trajectory.collections}
    assert marked["wrong fix"] == 3 and marked["another tile, right fix"] == 1
    legend = {t.get_text() for t in trajectory.get_legend().get_texts()}
    assert {"wrong fix", "another tile, right fix"} <= legend


def test_the_headline_position_error_says_which_frames_it_covers(
    drawn: tuple[str, list[Any]],
) -> None:
    text, _ = drawn
    kpis = dict(re.findall(r"<div>([^<]*)<b>([^<]*)</b></div>", text))
    assert kpis["position error p50 / p95 (m), every matched frame"] == "50.0 / 380 (5 frames)"
