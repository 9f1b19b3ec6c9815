"""Eval's false-confident measure judges a pick by where its inliers put the frame (ground
truth), not by the tile's label: an overlapping candidate that places the frame right is counted
apart, a pick whose inliers miss ground truth is a wrong fix."""

from __future__ import annotations

import math

import pytest

from c3_matcher_tools.evaluate import WRONG_FIX_PX, is_wrong_fix, metrics
from c3_matcher_tools.run import FrameOutcome
from c3_matcher_tools.testing.outcomes import frame_outcome


@pytest.mark.parametrize(
    ("outcome", "wrong"),
    [
        (frame_outcome(0), False),
        (frame_outcome(0, correct=False, error_px=3.0), False),  # overlapping pick, right place
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
    assert m.to_json()["C3-IT-05"] == {"insufficient": 1, "absent_frames": 2, "pass": False}
