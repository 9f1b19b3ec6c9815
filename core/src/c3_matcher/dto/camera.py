"""What the nav camera gives: its frames and its calibration.

Pixels are 0-based, origin at the centre of the top-left pixel, points in (x, y) order. Images
are ``uint8`` RGB ``(H, W, 3)`` or grey ``(H, W)``.
"""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.dto.geo import Attitude

MAX_HEIGHT_ABOVE_GROUND_M = 100_000.0  # above this a "height" is a units or sensor error
MAX_K_CONDITION = 1e12  # a K this ill-conditioned cannot be inverted reliably


def _check_image(image: object, field_name: str) -> NDArray[np.uint8]:
    arr = v.array(image, field_name, dtype=np.uint8)
    v.require(
        arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3),
        field_name,
        f"expected (H, W) or (H, W, 3), got {arr.shape}",
    )
    v.require(
        arr.shape[0] >= 16 and arr.shape[1] >= 16,
        field_name,
        f"image too small: {arr.shape[1]}x{arr.shape[0]} px (minimum 16x16)",
    )
    return arr


@dataclass(frozen=True, slots=True)
class NavCameraFrame:
    """One nav-camera frame (C1): the raw (distorted) image and what is known of the pose.

    ``image`` is uint8 RGB (H, W, 3) or grey (H, W), as captured. ``captured_at_ns`` is the
    capture time in ns, on the matcher's clock in flight (its age at matching is then the FDR
    records' ``recorded_at_ns`` minus it); a replayed dataset gives its own flight time, from its
    first frame, while the matcher's clock is the host's. ``attitude`` and
    ``height_above_ground_m`` are optional; without attitude no rectification happens, without
    height no GSD scaling.
    """

    frame_id: uuid.UUID
    image: NDArray[np.uint8]
    captured_at_ns: int
    attitude: Attitude | None = None
    height_above_ground_m: float | None = None

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.frame_id, uuid.UUID),
            "frame.frame_id",
            f"expected uuid.UUID, got {type(self.frame_id).__name__}",
        )
        # a private read-only copy: the caller's buffer may be reused by the camera driver
        object.__setattr__(self, "image", v.frozen_copy(_check_image(self.image, "frame.image")))
        captured = v.non_negative_int(self.captured_at_ns, "frame.captured_at_ns")
        v.require(captured < 2**63, "frame.captured_at_ns", f"exceeds int64 ns, got {captured}")
        v.require(
            self.attitude is None or isinstance(self.attitude, Attitude),
            "frame.attitude",
            f"expected Attitude or None, got {type(self.attitude).__name__}",
        )
        if self.height_above_ground_m is not None:
            h = v.finite_float(self.height_above_ground_m, "frame.height_above_ground_m")
            v.require(h > 0, "frame.height_above_ground_m", f"must be > 0, got {h}")
            v.require(
                h <= MAX_HEIGHT_ABOVE_GROUND_M,
                "frame.height_above_ground_m",
                f"must be <= {MAX_HEIGHT_ABOVE_GROUND_M:g} m (a UAV's height above ground), "
                f"got {h:g}",
            )


def _check_principal_point(k: NDArray[np.float64], image_size: tuple[int, int]) -> None:
    """Refuse a principal point (cx, cy) more than an image width (height) outside the image:
    the optical axis of a real camera meets its sensor, near the centre (a shift lens or a
    crop from one corner of a larger sensor moves it towards the edge, never a whole image
    beyond it), so such a K is for another image size or not in px, and would otherwise be
    blamed later on the attitude (the camera seeing no ground)."""
    width, height = image_size
    cx, cy = float(k[0, 2]), float(k[1, 2])
    v.require(
        -width <= cx <= 2 * width and -height <= cy <= 2 * height,
        "calibration.K",
        f"principal point ({cx:g}, {cy:g}) px lies more than an image width or height outside "
        f"the {width}x{height} px image (cx in [{-width}, {2 * width}], cy in [{-height}, "
        f"{2 * height}] expected): K is for another image size, or not in px",
    )


@dataclass(frozen=True, slots=True)
class CameraCalibration:
    """Intrinsics of the nav camera (C5 artifact).

    ``K`` float64 (3, 3) in pixels; ``distortion`` float64 (N,) OpenCV coefficients
    (k1, k2, p1, p2[, k3[, ...]]), N in {0, 4, 5, 8, 12, 14}; ``image_size`` (width, height) px;
    ``camera_to_body`` float64 (3, 3) rotation taking camera-frame vectors to the NED body frame,
    or None for the default mount (straight down, image top towards the nose).
    """

    K: NDArray[np.float64]
    distortion: NDArray[np.float64]
    image_size: tuple[int, int]
    camera_to_body: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        k = v.frozen_copy(v.array(self.K, "calibration.K", dtype=np.float64, shape=(3, 3)))
        v.require(k[0, 0] > 0 and k[1, 1] > 0, "calibration.K", "focal lengths must be > 0")
        v.require(
            bool(np.allclose(k[2], [0.0, 0.0, 1.0])), "calibration.K", "last row must be [0, 0, 1]"
        )
        with np.errstate(all="ignore"):
            cond = float(np.linalg.cond(k))
        v.require(
            math.isfinite(cond) and cond < MAX_K_CONDITION,
            "calibration.K",
            f"is singular or ill-conditioned (condition number {cond:.3g})",
        )
        object.__setattr__(self, "K", k)
        dist = v.frozen_copy(
            v.array(self.distortion, "calibration.distortion", dtype=np.float64, ndim=1)
        )
        v.require(
            dist.shape[0] in (0, 4, 5, 8, 12, 14),
            "calibration.distortion",
            f"expected 0, 4, 5, 8, 12 or 14 coefficients, got {dist.shape[0]}",
        )
        object.__setattr__(self, "distortion", dist)
        field = "calibration.image_size"
        size = v.items(self.image_size, field, "(width, height)")
        v.require(len(size) == 2, field, f"expected (width, height), got {self.image_size!r}")
        width = v.positive_int(size[0], field, "width")
        object.__setattr__(self, "image_size", (width, v.positive_int(size[1], field, "height")))
        _check_principal_point(k, self.image_size)
        if self.camera_to_body is not None:
            r = v.frozen_copy(
                v.array(
                    self.camera_to_body,
                    "calibration.camera_to_body",
                    dtype=np.float64,
                    shape=(3, 3),
                )
            )
            v.require(
                bool(np.allclose(r @ r.T, np.eye(3), atol=1e-6))
                and bool(np.isclose(np.linalg.det(r), 1.0, atol=1e-6)),
                "calibration.camera_to_body",
                "must be a rotation matrix",
            )
            object.__setattr__(self, "camera_to_body", r)

    @classmethod
    def pinhole(
        cls, width: int, height: int, focal_px: float, distortion: tuple[float, ...] = ()
    ) -> CameraCalibration:
        k = np.array(
            [[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2], [0, 0, 1]],
            dtype=np.float64,
        )
        return cls(k, np.array(distortion, dtype=np.float64), (width, height))
