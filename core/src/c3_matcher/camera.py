"""Camera geometry shared by preprocessing and simulation: rotations, lens model, homographies.

Conventions:

- Pixels are 0-based, origin at the centre of the top-left pixel (OpenCV), points are (x, y).
- World and body frames are NED (x north / forward, y east / right, z down). Attitude is
  aerospace Z-Y-X: ``R_world_from_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, yaw from true north.
- The camera frame is OpenCV's (x right, y down, z along the optical axis). The default mount
  (``calibration.camera_to_body is None``) looks straight down with the image top towards the
  nose: ``R_body_from_camera`` has columns x_c -> (0, 1, 0), y_c -> (-1, 0, 0), z_c -> (0, 0, 1).
- The "virtual nadir north-up camera" (the tiles' view) has ``R_world_from_virtual`` equal to
  the default mount at zero attitude: image right = east, image down = south, axis = down.
- The lens model is OpenCV's (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]) acting on
  normalised rays ``(x/z, y/z)``; "undistorted pixels" are ``K @ (x/z, y/z, 1)`` with the
  calibration's own K. As in OpenCV, the lens functions (distorted side) use fx, fy, cx, cy
  and ignore a skew K[0, 1]; the homographies (undistorted side) use the full K.

Every function is pure and vectorised over points: arrays of shape (N, 2) in, (N, 2) out.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration

__all__ = [
    "DEFAULT_BODY_FROM_CAMERA",
    "MAX_OFF_NADIR_DEG",
    "apply_homography",
    "body_from_camera",
    "clip_polygon",
    "distort_normalized",
    "distort_points",
    "image_boundary",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_world_from_body",
    "rotation_world_from_camera",
    "undistort_normalized",
    "undistort_points",
    "virtual_from_camera",
    "world_from_virtual",
]

#: R_body_from_camera of the default mount: looking down, image top towards the nose.
DEFAULT_BODY_FROM_CAMERA: F64 = np.array(
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=np.float64
)
DEFAULT_BODY_FROM_CAMERA.setflags(write=False)

#: The farthest from nadir (degrees) a ray is taken to see usable ground: the query is clipped
#: to it before matching and the georeferenced footprint after (grazing rays beyond it see the
#: ground too thinly to match, and a map's error there is magnified without bound).
MAX_OFF_NADIR_DEG = 75.0


def rot_x(angle: float) -> F64:
    """Right-handed rotation about x by ``angle`` radians (active, column vectors)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> F64:
    """Right-handed rotation about y by ``angle`` radians (active, column vectors)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> F64:
    """Right-handed rotation about z by ``angle`` radians (active, column vectors)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_world_from_body(attitude: Attitude) -> F64:
    """``R_world_from_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (NED, aerospace Z-Y-X)."""
    return rot_z(attitude.yaw) @ rot_y(attitude.pitch) @ rot_x(attitude.roll)


def body_from_camera(calibration: CameraCalibration) -> F64:
    """The calibration's ``camera_to_body`` rotation, or the default downward mount."""
    if calibration.camera_to_body is None:
        return DEFAULT_BODY_FROM_CAMERA.copy()
    return np.asarray(calibration.camera_to_body, dtype=np.float64).copy()


def rotation_world_from_camera(attitude: Attitude, calibration: CameraCalibration) -> F64:
    """``R_world_from_camera = R_world_from_body @ R_body_from_camera``."""
    return rotation_world_from_body(attitude) @ body_from_camera(calibration)


def world_from_virtual() -> F64:
    """``R_world_from_virtual`` of the nadir north-up camera (x east, y south, z down)."""
    return DEFAULT_BODY_FROM_CAMERA.copy()


def virtual_from_camera(attitude: Attitude, calibration: CameraCalibration) -> F64:
    """``R_virtual_from_camera = R_world_from_virtual.T @ R_world_from_camera``."""
    return world_from_virtual().T @ rotation_world_from_camera(attitude, calibration)


def _as_points(pts: ArrayLike) -> F64:
    arr = np.asarray(pts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        arr = arr.reshape(-1, 2)
    return arr


def apply_homography(h: ArrayLike, pts: ArrayLike) -> F64:
    """Map (N, 2) points through the 3x3 homography ``h`` (points with w == 0 become inf)."""
    p = _as_points(pts)
    hm = np.asarray(h, dtype=np.float64)
    q = p @ hm[:, :2].T + hm[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return q[:, :2] / q[:, 2:3]


def _project_rays(xy: F64, calibration: CameraCalibration) -> F64:
    """Apply the OpenCV lens model to normalised rays and K (fx, fy, cx, cy) -> ORIGINAL px."""
    d = np.zeros(14)
    d[: calibration.distortion.size] = calibration.distortion
    k = calibration.K
    if d[12] != 0.0 or d[13] != 0.0:  # tilted sensor model: let OpenCV do it
        obj = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1).reshape(-1, 1, 3)
        img, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), k, d)
        return np.asarray(img, dtype=np.float64).reshape(-1, 2)
    x, y = xy[:, 0], xy[:, 1]
    with np.errstate(all="ignore"):  # an absurd lens overflows: inf/nan, which callers refuse
        if not np.any(d):
            xd, yd = x, y
        else:
            k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d[:12]
            r2 = x * x + y * y
            r4 = r2 * r2
            radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
            xy2 = 2 * x * y
            xd = x * radial + p1 * xy2 + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
            yd = y * radial + p1 * (r2 + 2 * y * y) + p2 * xy2 + s3 * r2 + s4 * r4
        return np.stack([k[0, 0] * xd + k[0, 2], k[1, 1] * yd + k[1, 2]], axis=1)


def distort_normalized(rays_xy: ArrayLike, calibration: CameraCalibration) -> F64:
    """Normalised undistorted rays (x/z, y/z) (N, 2) -> ORIGINAL (distorted) pixels (N, 2).

    The exact OpenCV forward lens model (as ``cv2.projectPoints``), vectorised in numpy; the
    projection uses fx, fy, cx, cy (OpenCV's lens functions ignore the skew K[0, 1]).
    """
    xy = _as_points(rays_xy)
    if xy.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.float64)
    return _project_rays(xy, calibration)


def _pixels_to_rays(px: F64, k: F64) -> F64:
    """Undistorted px -> normalised rays with the full K (skew included)."""
    rays = np.empty_like(px)
    rays[:, 1] = (px[:, 1] - k[1, 2]) / k[1, 1]
    rays[:, 0] = (px[:, 0] - k[0, 2] - k[0, 1] * rays[:, 1]) / k[0, 0]
    return rays


def distort_points(undistorted_px: ArrayLike, calibration: CameraCalibration) -> F64:
    """Undistorted pixels (N, 2) (``K @ ray``) -> ORIGINAL (distorted) pixels (N, 2)."""
    return distort_normalized(
        _pixels_to_rays(_as_points(undistorted_px), calibration.K), calibration
    )


def undistort_normalized(
    original_px: ArrayLike, calibration: CameraCalibration, iterations: int = 3
) -> F64:
    """ORIGINAL (distorted) pixels (N, 2) -> normalised undistorted rays (x/z, y/z) (N, 2).

    OpenCV's fixed-point iteration (``cv2.undistortPointsIter``, 20 iterations) followed by up
    to ``iterations`` Gauss-Newton refinements of the exact forward model, so re-distorting the
    result reproduces the input to ~1e-9 px for any well-behaved (monotonic) lens.
    """
    p = _as_points(original_px)
    if p.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.float64)
    k = calibration.K
    if calibration.distortion.size == 0 or not np.any(calibration.distortion):
        return np.stack([(p[:, 0] - k[0, 2]) / k[0, 0], (p[:, 1] - k[1, 2]) / k[1, 1]], axis=1)
    criteria = (cv2.TERM_CRITERIA_COUNT, 20, 0.0)
    rays = np.asarray(
        cv2.undistortPointsIter(
            p.reshape(-1, 1, 2), k, calibration.distortion, np.eye(3), np.eye(3), criteria
        ),
        dtype=np.float64,
    ).reshape(-1, 2)
    eps = 1e-7
    for _ in range(iterations):
        f0 = _project_rays(rays, calibration)
        resid = p - f0
        bad = np.max(np.abs(resid), axis=1) > 1e-9
        if not np.any(bad):
            break
        rb, fb, eb = rays[bad], f0[bad], resid[bad]
        fx = (_project_rays(rb + np.array([eps, 0.0]), calibration) - fb) / eps
        fy = (_project_rays(rb + np.array([0.0, eps]), calibration) - fb) / eps
        a, b, c, d = fx[:, 0], fy[:, 0], fx[:, 1], fy[:, 1]
        det = a * d - b * c
        ok = np.abs(det) > 1e-12
        safe = np.where(ok, det, 1.0)
        dx = np.where(ok, (d * eb[:, 0] - b * eb[:, 1]) / safe, 0.0)
        dy = np.where(ok, (-c * eb[:, 0] + a * eb[:, 1]) / safe, 0.0)
        rays[bad] = rb + np.stack([dx, dy], axis=1)
    return rays


def undistort_points(original_px: ArrayLike, calibration: CameraCalibration) -> F64:
    """ORIGINAL (distorted) pixels (N, 2) -> undistorted pixels (N, 2), ``K @ ray``."""
    rays = undistort_normalized(original_px, calibration)
    k = calibration.K
    return np.stack(
        [k[0, 0] * rays[:, 0] + k[0, 1] * rays[:, 1] + k[0, 2], k[1, 1] * rays[:, 1] + k[1, 2]],
        axis=1,
    )


def image_boundary(width: int, height: int, samples_per_side: int = 64) -> F64:
    """Closed polygon (N, 2) along the outer pixel centres of a width x height image, clockwise
    in image coordinates (top edge left to right first), without repeating the first vertex."""
    n = max(2, samples_per_side)
    xs = np.linspace(0.0, width - 1.0, n)
    ys = np.linspace(0.0, height - 1.0, n)
    top = np.stack([xs[:-1], np.zeros(n - 1)], axis=1)
    right = np.stack([np.full(n - 1, width - 1.0), ys[:-1]], axis=1)
    bottom = np.stack([xs[::-1][:-1], np.full(n - 1, height - 1.0)], axis=1)
    left = np.stack([np.zeros(n - 1), ys[::-1][:-1]], axis=1)
    return np.concatenate([top, right, bottom, left], axis=0)


def clip_polygon(
    vertices: NDArray[np.float64], value: Callable[[NDArray[np.float64]], NDArray[np.float64]]
) -> F64:
    """Sutherland-Hodgman clip of a closed polygon (N, D) to the region ``value(v) >= 0``.

    ``value`` maps (M, D) vertices to (M,) signed values; crossings are placed by linear
    interpolation of the value along each edge (exact for an affine ``value``, accurate to
    second order in the edge length otherwise). Returns the clipped polygon (K, D), possibly
    empty.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape[0] == 0:
        return v
    s = np.asarray(value(v), dtype=np.float64)
    if bool(np.all(s >= 0)):
        return v
    if bool(np.all(s < 0)):
        return v[:0]
    out: list[NDArray[np.float64]] = []
    n = v.shape[0]
    for i in range(n):
        j = (i + 1) % n
        a_in, b_in = s[i] >= 0, s[j] >= 0
        if a_in:
            out.append(v[i])
        if a_in != b_in:
            t = s[i] / (s[i] - s[j])
            out.append(v[i] + t * (v[j] - v[i]))
    return np.asarray(out, dtype=np.float64).reshape(-1, v.shape[1])
