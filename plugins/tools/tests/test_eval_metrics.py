"""Eval's false-confident measure judges a pick by where its inliers put the frame (ground
truth), not by the tile's label: an overlapping candidate that places the frame right is counted
apart, a pick whose inliers miss ground truth is a wrong fix."""

from __future__ import annotations

import math

import pytest

from c3_matcher_tools.evaluate import WRONG_FIX_PX, is_wrong_fix, metrics
from c3_matcher_tools.run import FrameOutcome, figure, summarize
from c3_matcher_tools.run.acceptance import IT03_BAR_PX
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome


@pytest.mark.parametrize(
    ("outcome", "wrong"),
    [
        (frame_outcome(0), False),
        (frame_outcome(0, correct=False, error_px=3.0), False),  # overlapping pick, right place
        (frame_outcome(0, correct=False, error_px=9.5), False),  # just within the bound
        (frame_outcome(0, correct=False, error_px=WRONG_FIX_PX + 0.1), True),
        (
            frame_outcome(0, correct=False, error_px=math.nan),
            True,
        ),  # unknown: never given the benefit
        (frame_outcome(0, correct=True, error_px=40.0), True),  # the true tile, wrongly registered
        (frame_outcome(0, status="insufficient"), False),
    ],
)
def test_a_pick_is_wrong_when_its_inliers_miss_ground_truth(
    outcome: FrameOutcome, wrong: bool
) -> None:
    assert is_wrong_fix(outcome) is wrong


def test_the_wrong_fix_bound_is_four_times_the_it03_bar() -> None:
    assert WRONG_FIX_PX == 4 * IT03_BAR_PX == 10.0


def test_metrics_count_wrong_fixes_and_right_fixes_on_another_tile_apart() -> None:
    run = [
        frame_outcome(0),
        frame_outcome(1, correct=False, error_px=3.0),
        frame_outcome(2, correct=False, error_px=300.0),
        frame_outcome(3, status="insufficient"),
        frame_outcome(4, status="insufficient", true_present=False),
        frame_outcome(5, correct=False, error_px=500.0, true_present=False),
    ]
    m = metrics(run, run[:1])
    assert m.correct_tile.correct == 1 and m.correct_tile.frames == 4
    assert m.false_confident.frames == (2, 5)
    assert m.false_confident.right_fix_other_tile == (1,)
    assert m.false_confident.passed is False
    assert m.to_json()["C3-IT-05"] == {
        "insufficient": 1,
        "absent_frames": 2,
        "tiles_unread_frames": [],
        "pass": False,
    }


def _unreadable(index: int) -> FrameOutcome:
    return frame_outcome(index, status=FrameStatus.UNREADABLE)


def test_an_unreadable_frame_counts_in_no_measure_and_no_summary_figure() -> None:
    """The camera's loss, not the matcher's: IT-04 and the run summary (replay's table, the
    flight report) count the same frames; IT-02 compares only frames the matcher ran twice."""
    run = [frame_outcome(0), frame_outcome(1, correct=False), _unreadable(2)]
    acc = metrics(run, [frame_outcome(0), _unreadable(2)])
    summary = summarize(run)
    assert (acc.correct_tile.correct, acc.correct_tile.frames) == (1, 2)
    assert (summary.correct_candidate, summary.true_present) == (1, 2)
    assert acc.determinism.frames_compared == 1  # frame 2 never reached the matcher
    nothing_ran = metrics([_unreadable(0)], [_unreadable(0)])
    assert nothing_ran.determinism.frames_compared == 0 and nothing_ran.determinism.passed is None


def test_the_summary_counts_frames_without_their_true_tile_as_it05_does() -> None:
    run = [
        frame_outcome(0, status=FrameStatus.INSUFFICIENT, true_present=False),
        frame_outcome(1, true_present=False),  # a pick where none was due
        frame_outcome(2, status=FrameStatus.UNREADABLE, true_present=False),
    ]
    acc, summary = metrics(run, []), summarize(run)
    assert (summary.absent_raised, summary.true_absent) == (1, 2)
    assert (acc.absent_raised.insufficient, acc.absent_raised.absent_frames) == (1, 2)


@pytest.mark.parametrize(
    ("value", "spec", "text"),
    [
        (0.0309, None, "0.031"),
        (0.0526, None, "0.053"),
        (1.234, None, "1.23"),
        (12.34, None, "12.3"),
        (1530.2, None, "1530"),
        (0.0, None, "0.0"),
        (0.0004, None, "0.000"),
        (None, None, "n/a"),
        (math.nan, ".0f", "n/a"),
        (math.inf, None, "n/a"),
        (1437.4, ".0f", "1437"),
    ],
)
def test_figures_keep_three_significant_digits_so_centimetres_never_read_as_zero(
    value: float | None, spec: str | None, text: str
) -> None:
    assert figure(value, spec) == text
