"""Frame outcomes as a run records them, for tests of what is computed from them (the C3-IT
figures, the tables, the reports) without running a matcher."""

from __future__ import annotations

import math

from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = ["frame_outcome"]


def frame_outcome(
    index: int,
    *,
    status: FrameStatus = FrameStatus.OK,
    inliers: int = 100,
    correct: bool | None = None,
    error_px: float = 1.0,
    true_present: bool = True,
    has_truth: bool = True,
) -> FrameOutcome:
    """Frame ``index``'s outcome: matched (``status`` "ok") with ``inliers`` and a mean inlier
    error of ``error_px`` against ground truth, or raised (any other ``status``). ``correct``
    (only when matched): the true tile picked; by default, when it is among the candidates and
    the flight has ground truth."""
    ok = status == FrameStatus.OK
    picked_true = true_present and has_truth if correct is None else correct
    return FrameOutcome(
        index=index,
        frame_id=f"f{index}",
        status=status,
        elapsed_ms=10.0,
        true_present=true_present,
        best_inliers=inliers if ok else 0,
        best_input_index=0 if ok else None,
        correct=ok and picked_true,
        mean_error_px=error_px if ok and has_truth else math.nan,
        residual_px=1.0 if ok else math.nan,
        fingerprint=str(index),
        error=None,
        result=None,
        has_truth=has_truth,
    )
