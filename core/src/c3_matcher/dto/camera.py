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
MAX_HALF_FIELD_OF_VIEW_DEG = 85.0
"""A pinhole image no wider than this each side of the optical axis: a focal length (px) below
``width / (2 tan 85 deg)`` gives a field of view beyond 170 deg, which no pinhole calibration
has (a fisheye's is no pinhole one); it is a focal length in mm or for a smaller image."""
FISHEYE_LENS_MODELS = frozenset(
    {"equidistant", "fisheye", "kannala_brandt", "kb4", "kb8", "fov", "omni", "double_sphere",
     "ds", "eucm", "mei", "scaramuzza"}
)  # fmt: skip
"""Lens models (as ROS, Kalibr, OpenCV and Basalt name them, lower case) whose coefficients are
not OpenCV's pinhole ones: 4 fisheye numbers read as k1, k2, p1, p2 would bend every ray."""
OTHER_LENS_MODEL_FIX = (
    "the matcher takes OpenCV's pinhole lens model (k1, k2, p1, p2[, k3...]) only: undistort "
    "the frames first (and give the undistorted images' K with no distortion), or calibrate "
    "the camera with OpenCV's model"
)
"""What to do about a calibration of one of :data:`FISHEYE_LENS_MODELS`."""
ROTATION_TOLERANCE = 1e-3
"""The most ``max |R^T R - I|`` a ``camera_to_body`` may deviate from a rotation: a rotation
printed to 4 decimals (a 45 deg mount as 0.7071) deviates by some 1e-4. Within it the matrix is
replaced by its nearest rotation; beyond it the matrix is no rotation, refused."""


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


def _check_focal_lengths(k: NDArray[np.float64], image_size: tuple[int, int]) -> None:
    """Refuse fx (fy) below the width (height) over ``2 tan(MAX_HALF_FIELD_OF_VIEW_DEG)``: a
    field of view beyond 170 deg, a focal length in mm (4.5 on a 640 px image: 178 deg) that
    would otherwise undistort every frame to a few central pixels and end in "no inliers"."""
    spread = 2.0 * math.tan(math.radians(MAX_HALF_FIELD_OF_VIEW_DEG))
    for name, focal, extent, side in (
        ("fx", float(k[0, 0]), image_size[0], "width"),
        ("fy", float(k[1, 1]), image_size[1], "height"),
    ):
        least = extent / spread
        v.require(
            focal >= least,
            "calibration.K",
            f"{name} = {focal:g} px is below {least:.3g} px, the image {side} {extent} px over "
            f"2 tan({MAX_HALF_FIELD_OF_VIEW_DEG:g} deg): a field of view beyond "
            f"{2 * MAX_HALF_FIELD_OF_VIEW_DEG:g} deg (a focal length in mm?)",
        )


_AS_GIVEN = 1e-6
"""A ``camera_to_body`` within this of a rotation (max |R^T R - I|) is one, written to float
precision: used as given."""


def _nearest_rotation(value: object) -> NDArray[np.float64]:
    """``value`` as a read-only rotation matrix: the nearest rotation (the orthonormal factor of
    its SVD) when it deviates from one by at most ``ROTATION_TOLERANCE`` (a matrix printed to a
    few decimals); refused naming the deviation beyond it, or when it is a reflection."""
    field = "calibration.camera_to_body"
    r = v.array(value, field, dtype=np.float64, shape=(3, 3))
    deviation = float(np.max(np.abs(r.T @ r - np.eye(3))))
    v.require(
        deviation <= ROTATION_TOLERANCE,
        field,
        f"must be a rotation matrix: max |R^T R - I| is {deviation:.3g}, more than "
        f"{ROTATION_TOLERANCE:g}",
    )
    v.require(
        float(np.linalg.det(r)) > 0,
        field,
        "is a reflection (determinant -1), not a rotation: is one camera or body axis "
        "flipped (a left-handed frame?)",
    )
    if deviation <= _AS_GIVEN:  # a rotation to float precision: kept as given, bit for bit
        return v.frozen_copy(r)
    u, _, vt = np.linalg.svd(r)
    return v.frozen_copy(np.ascontiguousarray(u @ vt, dtype=np.float64))


@dataclass(frozen=True, slots=True)
class CameraCalibration:
    """Intrinsics of the nav camera (C5 artifact).

    ``K`` float64 (3, 3) in pixels; ``distortion`` float64 (N,) OpenCV coefficients
    (k1, k2, p1, p2[, k3[, ...]]), N in {0, 4, 5, 8, 12, 14}; ``image_size`` (width, height) px;
    ``camera_to_body`` float64 (3, 3) rotation taking camera-frame vectors (OpenCV: x right, y
    down, z along the optical axis) to the body frame (FRD), or None for the default mount
    (straight down, image top towards the nose); one within ``ROTATION_TOLERANCE`` of a rotation
    is replaced by its nearest rotation. ``K``'s focal lengths give a field of view within
    ``2 * MAX_HALF_FIELD_OF_VIEW_DEG``.
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
        _check_focal_lengths(k, self.image_size)
        if self.camera_to_body is not None:
            object.__setattr__(self, "camera_to_body", _nearest_rotation(self.camera_to_body))

    @classmethod
    def pinhole(
        cls, width: int, height: int, focal_px: float, distortion: tuple[float, ...] = ()
    ) -> CameraCalibration:
        k = np.array(
            [[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2], [0, 0, 1]],
            dtype=np.float64,
        )
        return cls(k, np.array(distortion, dtype=np.float64), (width, height))
