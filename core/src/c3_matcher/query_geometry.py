"""Where every engine pixel of a prepared query comes from: :class:`QueryGeometry` (the
rectifying homography, the canvas, the engine sizes and the footprint; see
:mod:`c3_matcher.preprocess` for how it is computed)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration

__all__ = ["QueryGeometry"]


@dataclass(frozen=True)
class QueryGeometry:
    """Where every engine pixel of a prepared query comes from (no pixels involved).

    ``working_from_undistorted`` H_w (3x3); ``working_size``, ``content_size`` (engine size
    before pad/crop) and ``final_size`` (engine image) as (w, h) px; ``working_from_engine`` 3x3
    affine; ``footprint_working`` the frame's (clipped) boundary polygon (N, 2) in WORKING px;
    ``nadir_working_px`` (rectified only); ``working_gsd_m`` m/px at nadir when the height is
    known; ``nadir_shrink`` ORIGINAL px per engine px near the optical axis.
    """

    working_from_undistorted: F64
    working_size: tuple[int, int]
    content_size: tuple[int, int]
    final_size: tuple[int, int]
    working_from_engine: F64
    footprint_working: F64
    nadir_working_px: tuple[float, float] | None
    working_gsd_m: float | None
    nadir_shrink: float

    def working_per_engine(self) -> float:
        """WORKING px per engine px at the engine image's centre (sqrt |det J| of
        ``working_from_engine``; for a homography M at p, det J = det M / w(p)^3)."""
        m = self.working_from_engine
        w = m[2] @ np.array([self.content_size[0] / 2, self.content_size[1] / 2, 1.0])
        return float(np.sqrt(abs(np.linalg.det(m) / w**3)))

    def original_per_working(self) -> float:
        """ORIGINAL px per WORKING px near the optical axis."""
        return self.nadir_shrink / self.working_per_engine()

    def footprint_engine(self) -> F64:
        """The footprint polygon (N, 2) in ENGINE px."""
        return cam.apply_homography(np.linalg.inv(self.working_from_engine), self.footprint_working)

    def remap_maps(
        self,
        calibration: CameraCalibration,
        source_scale: tuple[float, float] = (1.0, 1.0),
        m1type: int = cv2.CV_32FC1,
    ) -> tuple[NDArray[Any], NDArray[Any]]:
        """``cv2.remap`` maps ENGINE px -> ORIGINAL px (exact lens model per pixel), or -> px of
        the ORIGINAL frame resized by ``source_scale`` (sx, sy) (area-aligned convention).

        ``cv2.initUndistortRectifyMap`` computes ``ray = inv(newK @ R) @ p_engine`` and maps it
        through the lens and ``cameraMatrix``: with ``newK = I`` and ``R = A_e^-1 @ H_w @ K``
        the ray is ``K^-1 @ H_w^-1 @ A_e @ p_engine``, the engine pixel's camera ray.
        """
        k = calibration.K
        ax, ay = source_scale
        k_map = (
            np.array([[ax, 0.0, 0.5 * ax - 0.5], [0.0, ay, 0.5 * ay - 0.5], [0.0, 0.0, 1.0]]) @ k
        )
        r_arg = np.linalg.inv(self.working_from_engine) @ self.working_from_undistorted @ k
        map1, map2 = cv2.initUndistortRectifyMap(
            k_map, calibration.distortion, r_arg, np.eye(3), self.final_size, m1type
        )
        return np.asarray(map1), np.asarray(map2)
