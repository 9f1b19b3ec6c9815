"""Camera geometry: rotation conventions, lens model, homography and polygon helpers."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.dto import Attitude, CameraCalibration

BARREL = (-0.12, 0.03, 0.0008, -0.0005, 0.002)
RATIONAL = (-0.12, 0.03, 0.0008, -0.0005, 0.002, 0.01, 0.003, 0.001, 0.001, 0.002, 0.0005, 0.0003)
TILTED = (*RATIONAL, 0.01, -0.02)


def test_yaw_90_turns_the_nose_east() -> None:
    r = cam.rotation_world_from_body(Attitude(0.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-12)


def test_positive_pitch_raises_the_nose_and_roll_drops_the_right_wing() -> None:
    up = cam.rotation_world_from_body(Attitude(0.0, math.radians(30), 0.0)) @ [1, 0, 0]
    np.testing.assert_allclose(up, [math.cos(math.radians(30)), 0, -0.5], atol=1e-12)
    right = cam.rotation_world_from_body(Attitude(math.radians(30), 0.0, 0.0)) @ [0, 1, 0]
    np.testing.assert_allclose(right, [0, math.cos(math.radians(30)), 0.5], atol=1e-12)


def test_zyx_order_is_yaw_then_pitch_then_roll() -> None:
    att = Attitude(0.1, -0.2, 0.3)
    expected = cam.rot_z(0.3) @ cam.rot_y(-0.2) @ cam.rot_x(0.1)
    np.testing.assert_allclose(cam.rotation_world_from_body(att), expected, atol=1e-15)
    assert not np.allclose(expected, cam.rot_x(0.1) @ cam.rot_y(-0.2) @ cam.rot_z(0.3))


def test_default_mount_looks_down_with_image_top_to_the_nose() -> None:
    cal = CameraCalibration.pinhole(64, 48, 50.0)
    r_bc = cam.body_from_camera(cal)
    np.testing.assert_allclose(r_bc @ [0, 0, 1], [0, 0, 1])  # optical axis -> down
    np.testing.assert_allclose(r_bc @ [0, -1, 0], [1, 0, 0])  # image up -> forward
    np.testing.assert_allclose(r_bc @ [1, 0, 0], [0, 1, 0])  # image right -> right wing
    np.testing.assert_allclose(cam.virtual_from_camera(Attitude(0, 0, 0), cal), np.eye(3))


def test_camera_to_body_from_the_calibration_is_used() -> None:
    mount = cam.rot_z(0.5) @ cam.DEFAULT_BODY_FROM_CAMERA
    cal = CameraCalibration(
        CameraCalibration.pinhole(64, 48, 50.0).K, np.zeros(0), (64, 48), camera_to_body=mount
    )
    np.testing.assert_allclose(cam.body_from_camera(cal), mount)
    np.testing.assert_allclose(
        cam.virtual_from_camera(Attitude(0, 0, 0), cal),
        cam.DEFAULT_BODY_FROM_CAMERA.T @ mount,
        atol=1e-15,
    )


def test_virtual_camera_is_north_up() -> None:
    r_wv = cam.world_from_virtual()
    np.testing.assert_allclose(r_wv @ [1, 0, 0], [0, 1, 0])  # image right = east
    np.testing.assert_allclose(r_wv @ [0, 1, 0], [-1, 0, 0])  # image down = south


@pytest.mark.parametrize("coeffs", [BARREL, RATIONAL, TILTED])
def test_forward_lens_model_matches_opencv(coeffs: tuple[float, ...]) -> None:
    cal = CameraCalibration.pinhole(640, 480, 600.0, coeffs)
    rays = np.random.default_rng(1).uniform(-0.5, 0.5, (500, 2))
    ours = cam.distort_normalized(rays, cal)
    obj = np.concatenate([rays, np.ones((500, 1))], axis=1).reshape(-1, 1, 3)
    ref, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), cal.K, cal.distortion)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-9)


@pytest.mark.parametrize("coeffs", [BARREL, RATIONAL, TILTED])
def test_undistort_inverts_the_lens_model_exactly(coeffs: tuple[float, ...]) -> None:
    cal = CameraCalibration.pinhole(640, 480, 600.0, coeffs)
    xs, ys = np.meshgrid(np.linspace(0, 639, 41), np.linspace(0, 479, 31))
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = cam.undistort_normalized(px, cal)
    np.testing.assert_allclose(cam.distort_normalized(rays, cal), px, atol=1e-8)
    und = cam.undistort_points(px, cal)
    np.testing.assert_allclose(cam.distort_points(und, cal), px, atol=1e-8)
    # barrel: corners move outwards when undistorted
    corner = cam.undistort_points([[0.0, 0.0]], cal)[0]
    assert corner[0] < 0 and corner[1] < 0


def test_no_distortion_is_the_pinhole() -> None:
    cal = CameraCalibration.pinhole(640, 480, 600.0)
    px = np.array([[0.0, 0.0], [319.5, 239.5], [639.0, 100.0]])
    np.testing.assert_allclose(cam.undistort_points(px, cal), px, atol=1e-12)
    np.testing.assert_allclose(cam.undistort_normalized(px, cal)[1], [0.0, 0.0])


def test_apply_homography() -> None:
    h = np.array([[2.0, 0.0, 1.0], [0.0, 3.0, -1.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(
        cam.apply_homography(h, [[1.0, 1.0], [0.0, 2.0]]), [[3.0, 2.0], [1.0, 5.0]]
    )
    persp = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.5, 0, 1.0]])
    np.testing.assert_allclose(cam.apply_homography(persp, [[2.0, 4.0]]), [[1.0, 2.0]])


def test_image_boundary_walks_the_outer_pixel_centres() -> None:
    b = cam.image_boundary(10, 6, samples_per_side=5)
    assert b.shape == (16, 2)
    np.testing.assert_allclose(b[0], [0, 0])
    assert {tuple(p) for p in b} >= {(0.0, 0.0), (9.0, 0.0), (9.0, 5.0), (0.0, 5.0)}
    assert b[:, 0].min() == 0 and b[:, 0].max() == 9 and b[:, 1].max() == 5


def test_clip_polygon_by_half_plane() -> None:
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    clipped = cam.clip_polygon(square, lambda v: v[:, 0] - 0.5)
    area = 0.5 * abs(
        np.dot(clipped[:, 0], np.roll(clipped[:, 1], 1))
        - np.dot(clipped[:, 1], np.roll(clipped[:, 0], 1))
    )
    assert area == pytest.approx(3.0)
    assert clipped[:, 0].min() == pytest.approx(0.5)
    assert cam.clip_polygon(square, lambda v: v[:, 0] - 5).shape[0] == 0
    np.testing.assert_array_equal(cam.clip_polygon(square, lambda v: v[:, 0] + 1), square)
