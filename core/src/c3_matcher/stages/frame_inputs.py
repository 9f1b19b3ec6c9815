"""What ``match`` checks of its arguments before the frame is matched, and which frame its
records are about (``pipeline.PipelineMatcher``)."""

from __future__ import annotations

from typing import Any

from c3_matcher.dto import CameraCalibration, NavCameraFrame, RerankResult
from c3_matcher.errors import InvalidInputError

__all__ = ["check_inputs", "frame_id_of"]


def frame_id_of(frame: object, rerank: object, calibration: object) -> Any:
    """The frame a call's records are about: the re-rank's, or the nav frame's when valid
    inputs carry a re-rank made for another frame."""
    if (
        isinstance(frame, NavCameraFrame)
        and isinstance(rerank, RerankResult)
        and isinstance(calibration, CameraCalibration)
        and rerank.frame_id != frame.frame_id
    ):
        return frame.frame_id
    return getattr(rerank, "frame_id", None)


def check_inputs(frame: object, rerank: object, calibration: object) -> None:
    """Refuse wrong types (a caller's programming error). ``frame=None`` and a re-rank of
    another frame are conditions of flight, answered with the contract's errors."""
    if frame is not None and not isinstance(frame, NavCameraFrame):
        raise InvalidInputError("frame", f"expected NavCameraFrame, got {type(frame).__name__}")
    if not isinstance(rerank, RerankResult):
        raise InvalidInputError(
            "rerank_result", f"expected RerankResult, got {type(rerank).__name__}"
        )
    if not isinstance(calibration, CameraCalibration):
        raise InvalidInputError(
            "calibration", f"expected CameraCalibration, got {type(calibration).__name__}"
        )
