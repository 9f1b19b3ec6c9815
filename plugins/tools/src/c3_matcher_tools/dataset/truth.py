"""Scoring matches against a dataset's ground truth (the same measure as
:func:`c3_matcher_tools.sim.scenario.inlier_errors_px`: ORIGINAL frame pixels)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from c3_matcher import camera as cam
from c3_matcher.dto import CameraCalibration

__all__ = ["inlier_errors_px"]


def inlier_errors_px(
    h_tile_to_undistorted: NDArray[np.float64],
    calibration: CameraCalibration,
    correspondences: NDArray[np.float32],
) -> NDArray[np.float64]:
    """Per correspondence (x_query, y_query, x_tile, y_tile), the distance in ORIGINAL
    (distorted) frame px between the reported query point and where the ground truth puts the
    reported tile point (tile px -> undistorted frame px by the homography, then distorted)."""
    corr = np.asarray(correspondences, dtype=np.float64).reshape(-1, 4)
    if corr.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    und = cam.apply_homography(h_tile_to_undistorted, corr[:, 2:4])
    truth = cam.distort_points(und, calibration)
    return np.asarray(np.linalg.norm(truth - corr[:, 0:2], axis=1), dtype=np.float64)
