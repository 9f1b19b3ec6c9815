"""The working canvas a steep frame is rectified onto is bounded, by default at three times the
frame's long side: a wide footprint costs no more than that to extract from."""

from __future__ import annotations

import math
import uuid

import numpy as np
import pytest

from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame
from c3_matcher.prepared import InputRule
from c3_matcher.preprocess import FramePreprocessor

W, H = 640, 480


def _working_size(pre: FramePreprocessor, pitch_deg: float) -> tuple[int, int]:
    """The working canvas of a grey 640 x 480 frame (focal 1500 px) pitched ``pitch_deg``."""
    frame = NavCameraFrame(
        uuid.uuid4(), np.full((H, W, 3), 128, np.uint8), 0, Attitude(0, math.radians(pitch_deg), 0)
    )
    prepared = pre.prepare_query(frame, CameraCalibration.pinhole(W, H, 1500.0), None)
    return prepared.working_size


@pytest.mark.parametrize("pitch_deg", [64.0, 70.0])
def test_a_steep_frames_canvas_stops_at_three_times_its_long_side_by_default(pitch_deg):
    default = FramePreprocessor(InputRule(8192, 16))
    assert _working_size(default, pitch_deg) == (3 * W, 3 * W)
    wider = FramePreprocessor(InputRule(8192, 16), max_canvas_factor=4.0)
    assert max(_working_size(wider, pitch_deg)) > 3 * W  # the footprint is longer: bounded


def test_a_footprint_within_the_bound_is_kept_whole():
    default = FramePreprocessor(InputRule(8192, 16))
    assert max(_working_size(default, 50.0)) < 3 * W
    wider = FramePreprocessor(InputRule(8192, 16), max_canvas_factor=4.0)
    assert _working_size(default, 50.0) == _working_size(wider, 50.0)
