"""The C3-IT acceptance measures of one strategy's run over a flight with ground truth (see
:mod:`c3_matcher_tools.evaluate` for what each measures and its bar)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from c3_matcher_tools.run.records import FrameOutcome

__all__ = ["BARS", "IT03_BAR_PX", "WRONG_FIX_PX", "headline", "is_wrong_fix", "metrics"]

BARS = {
    "C3-IT-01": ">= 80 inliers (p5)",
    "C3-IT-02": "identical",
    "C3-IT-03": "< 2.5 px (p95)",
    "C3-IT-04": ">= 0.95",
    "C3-IT-05": "all absent frames",
}

IT03_BAR_PX = 2.5
WRONG_FIX_PX = 4 * IT03_BAR_PX
"""A returned pick is a wrong fix when its inliers' mean error against ground truth exceeds
this (ORIGINAL frame px): four times the IT-03 bar, a scale-free bound far below any
distractor's offset (>= 350 m, over 100 frame px on every shipped flight) and above the
per-inlier scatter of a right but imprecise fix (IT-03 means of 2-4 px across seasons)."""


def is_wrong_fix(outcome: FrameOutcome) -> bool:
    """A returned pick that places the frame wrong (see ``WRONG_FIX_PX``); a raise never is."""
    if outcome.status != "ok":
        return False
    error = outcome.mean_error_px
    return not (math.isfinite(error) and error <= WRONG_FIX_PX)


def metrics(run1: Sequence[FrameOutcome], run2: Sequence[FrameOutcome]) -> dict[str, Any]:
    """The C3-IT figures and pass flags of one strategy (see the module docstring)."""
    present = [o for o in run1 if o.has_truth and o.true_present]
    absent = [o for o in run1 if o.has_truth and not o.true_present]
    inliers = [float(o.best_inliers) for o in present]
    p5 = float(np.percentile(inliers, 5)) if inliers else math.nan
    correct = sum(o.correct for o in present)
    rate = correct / len(present) if present else math.nan
    raised = sum(o.status == "insufficient" for o in absent)
    return {
        "C3-IT-01": {"p5_best_inliers": p5, "frames": len(present), "pass": p5 >= 80},
        "C3-IT-02": _it02(run1, run2),
        "C3-IT-03": _it03(present),
        "C3-IT-04": {
            "correct_rate": rate,
            "correct": correct,
            "frames": len(present),
            "pass": bool(present) and rate >= 0.95,
        },
        "C3-IT-05": {
            "insufficient": raised,
            "absent_frames": len(absent),
            "pass": raised == len(absent),
        },
        "false_confident": _false_confident([o for o in run1 if o.has_truth]),
    }


def _it02(run1: Sequence[FrameOutcome], run2: Sequence[FrameOutcome]) -> dict[str, Any]:
    first = {o.index: o for o in run1}
    compared = [o for o in run2 if o.index in first]
    differing = [
        o.index
        for o in compared
        if (o.status, o.fingerprint) != (first[o.index].status, first[o.index].fingerprint)
    ]
    return {
        "frames_compared": len(compared),
        "differing_frames": differing,
        "pass": bool(compared) and not differing,
    }


def _it03(present: Sequence[FrameOutcome]) -> dict[str, Any]:
    positions = [o.position_error_m for o in present if o.status == "ok"]
    positions = [p for p in positions if math.isfinite(p)]
    errors = [
        o.mean_error_px for o in present if o.status == "ok" and math.isfinite(o.mean_error_px)
    ]
    p95 = float(np.percentile(errors, 95)) if errors else math.nan
    return {
        "p95_mean_error_px": p95,
        "frames_scored": len(errors),
        "median_mean_error_px": float(np.median(errors)) if errors else math.nan,
        "p95_position_error_m": float(np.percentile(positions, 95)) if positions else math.nan,
        "median_position_error_m": float(np.median(positions)) if positions else math.nan,
        "pass": bool(errors) and p95 < IT03_BAR_PX,
    }


def _false_confident(scored: Sequence[FrameOutcome]) -> dict[str, Any]:
    wrong = [o.index for o in scored if is_wrong_fix(o)]
    right_elsewhere = [
        o.index for o in scored if o.status == "ok" and not o.correct and not is_wrong_fix(o)
    ]
    return {
        "frames": wrong,
        "count": len(wrong),
        "of": len(scored),
        "rate": len(wrong) / len(scored) if scored else math.nan,
        "bound_px": WRONG_FIX_PX,
        "right_fix_other_tile": right_elsewhere,
        "pass": not wrong,
    }


def headline(m: dict[str, Any]) -> dict[str, Any]:
    """The figures of :func:`metrics` a strategy x flight summary row shows: correct tile of
    the frames whose true tile is present, IT-03 p95 (px), absent frames raised, and returned
    picks that are wrong fixes (false-confident) of those scored."""
    return {
        "correct": m["C3-IT-04"]["correct"],
        "present": m["C3-IT-04"]["frames"],
        "it03_p95_px": m["C3-IT-03"]["p95_mean_error_px"],
        "it05_raised": m["C3-IT-05"]["insufficient"],
        "absent": m["C3-IT-05"]["absent_frames"],
        "false_confident": m["false_confident"]["count"],
        "scored": m["false_confident"]["of"],
    }
