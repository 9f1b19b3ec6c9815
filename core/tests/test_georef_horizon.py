"""The footprint is the ground the frame sees: a frame tilted so far that its top edge looks above
the horizon maps that edge through the homography to points behind the camera (the map's third
coordinate changes sign there), and the edge just below it to points without bound away. The
footprint keeps the part of the frame within the off-nadir cone the query is clipped to before
matching, and a frame whose centre sees no ground there is not placed at all. A frame wholly
within the cone keeps exactly the footprint it always had.

The maps are the true ones of a camera over flat ground (:func:`_true_map`), normalised as a fit
leaves them (third coordinate 1 at px (0, 0), so the sign flips when that corner sees the sky),
and refitted from the ground part of the frame as the matcher's inliers would give it. The real
path, a rendered frame matched by the engine: ``tests/test_georef_horizon_match.py``."""

from __future__ import annotations

import math
import uuid

import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.dto import Attitude, CameraCalibration, CandidateMatchSet, MatchResult, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import (
    fit_query_to_tile,
    footprint_lonlat,
    georeference_result,
    tile_px_to_lonlat,
)

TILE_ID = TileId(21, 14.5955, 120.982)
TILE_SIZE = (1400, 1400)
GSD_M = 0.0968287
HEIGHT_M = 30.0
M_PER_DEG = 111_320.0


def _calibration(tilt_mount_deg: float = 0.0) -> CameraCalibration:
    k = np.array([[420.0, 0.0, 319.5], [0.0, 420.0, 239.5], [0.0, 0.0, 1.0]])
    mount = cam.rot_y(math.radians(tilt_mount_deg)) @ cam.DEFAULT_BODY_FROM_CAMERA
    return CameraCalibration(k, np.zeros(5), (640, 480), camera_to_body=mount)


def _true_map(
    calibration: CameraCalibration, attitude_deg: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """(UNDISTORTED px -> tile px of the camera ``HEIGHT_M`` over flat ground, the tile centred
    on the ground 25 m ahead of the nadir, the nadir's tile px). Ground (north, east) of a ray is
    ``HEIGHT_M * (ray_n, ray_e) / ray_down``; tile px are east and south of the centre."""
    r_wc = cam.rotation_world_from_camera(Attitude.from_degrees(*attitude_deg), calibration)
    yaw = math.radians(attitude_deg[2])
    aim_n, aim_e = 25.0 * math.cos(yaw), 25.0 * math.sin(yaw)
    cu, cv = (TILE_SIZE[0] - 1) / 2, (TILE_SIZE[1] - 1) / 2
    ground_to_tile = np.array(
        [
            [0.0, 1.0 / GSD_M, cu - aim_e / GSD_M],
            [-1.0 / GSD_M, 0.0, cv + aim_n / GSD_M],
            [0.0, 0.0, 1.0],
        ]
    )
    truth = (
        ground_to_tile @ np.diag([HEIGHT_M, HEIGHT_M, 1.0]) @ r_wc @ np.linalg.inv(calibration.K)
    )
    nadir = ground_to_tile @ np.array([0.0, 0.0, 1.0])
    return truth / truth[2, 2], nadir[:2]


def _ground_px(hom: np.ndarray, calibration: CameraCalibration) -> np.ndarray:
    """Px of the frame that see the ground within 70 deg of nadir: where inliers can be."""
    xs, ys = np.meshgrid(np.linspace(0, 639, 17), np.linspace(0, 479, 13))
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    rays = np.concatenate([px, np.ones((len(px), 1))], axis=1) @ np.linalg.inv(calibration.K).T
    third = rays @ (calibration.K.T @ hom[2])
    down = np.sign(np.linalg.det(hom)) * third / np.linalg.norm(rays, axis=1)
    return px[down / np.linalg.norm(calibration.K.T @ hom[2]) > math.cos(math.radians(70.0))]


def _along_and_range_m(
    ring: np.ndarray, nadir: np.ndarray, yaw_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each vertex's metres ahead of the nadir (along the heading) and away from it."""
    (lon_n, lat_n) = tile_px_to_lonlat(TILE_ID, TILE_SIZE, [nadir], GSD_M)[0]
    north = (ring[:, 1] - lat_n) * M_PER_DEG
    east = (ring[:, 0] - lon_n) * M_PER_DEG * math.cos(math.radians(lat_n))
    yaw = math.radians(yaw_deg)
    return north * math.cos(yaw) + east * math.sin(yaw), np.hypot(north, east)


@pytest.mark.parametrize("refit", [False, True])
@pytest.mark.parametrize(
    ("attitude_deg", "mount_deg"), [((0.0, 62.0, 30.0), 0.0), ((0.0, 35.0, 200.0), 28.0)]
)
def test_a_frame_whose_top_edge_sees_the_sky_has_its_footprint_ahead_of_the_vehicle(
    attitude_deg: tuple[float, float, float], mount_deg: float, refit: bool
) -> None:
    """Nose up 62 deg (the top edge 1.7 deg above the horizon), or an oblique mount: 9 of 28
    vertices lay up to 1.2 km behind the vehicle. Now every vertex is ahead of the nadir and
    within the 75 deg cone (``HEIGHT_M * tan 75`` = 112 m), the centre where the camera looks."""
    calibration = _calibration(mount_deg)
    truth, nadir = _true_map(calibration, attitude_deg)
    hom = truth
    if refit:
        px = _ground_px(truth, calibration)
        fitted = fit_query_to_tile(np.hstack([px, cam.apply_homography(truth, px)]), calibration)
        assert fitted is not None
        hom = fitted
    top = cam.apply_homography(hom, [[319.5, 0.0]])[0]
    assert np.isfinite(top).all()  # the top edge maps somewhere: behind the camera
    placed = footprint_lonlat(hom, TILE_ID, TILE_SIZE, calibration, GSD_M)
    assert placed is not None
    centre, ring = placed
    along, away = _along_and_range_m(ring, nadir, attitude_deg[2])
    assert along.min() > 0.0
    assert away.max() < HEIGHT_M * math.tan(math.radians(75.5))
    assert away.max() > HEIGHT_M * math.tan(math.radians(70.0))  # the cone, not less
    look = np.array([[319.5, 239.5]])
    expect = tile_px_to_lonlat(TILE_ID, TILE_SIZE, cam.apply_homography(truth, look), GSD_M)
    assert np.allclose(centre, expect[0], rtol=0, atol=1e-9)
    assert np.array_equal(ring[0], ring[-1]) and len(ring) >= 4
    d = ring - ring[0]
    assert float(np.sum(d[:-1, 0] * d[1:, 1] - d[1:, 0] * d[:-1, 1])) > 0  # counter-clockwise


@pytest.mark.parametrize(
    ("attitude_deg", "mount_deg"), [((0.0, 90.0, 0.0), 5.0), ((0.0, 80.0, 45.0), 0.0)]
)
def test_a_frame_whose_centre_sees_no_ground_within_the_cone_is_not_placed(
    attitude_deg: tuple[float, float, float], mount_deg: float
) -> None:
    """The principal point above the horizon (95 deg from nadir, the bottom of the frame on the
    ground) or on ground 80 deg off nadir: its centre would be behind the camera, or on ground
    too grazing for the map to place, so the result carries no centre and no footprint."""
    calibration = _calibration(mount_deg)
    truth, _ = _true_map(calibration, attitude_deg)
    px = _ground_px(truth, calibration)
    assert len(px) >= 4  # the matcher could have matched this frame
    assert footprint_lonlat(truth, TILE_ID, TILE_SIZE, calibration, GSD_M) is None
    rows = np.hstack([px, cam.apply_homography(truth, px)]).astype(np.float32)
    result = MatchResult(
        uuid.UUID(int=1),
        (CandidateMatchSet(TILE_ID, len(rows), rows, 0, 0.1),),
        0,
        0.1,
        0,
        "test",
        1,
        0,
        {},
    )
    out = georeference_result(result, calibration, [TILE_SIZE], GSD_M)
    assert set(out) == {"best_homography"}


def _old_footprint(
    hom: np.ndarray, calibration: CameraCalibration
) -> tuple[tuple[float, float], np.ndarray]:
    """The footprint as it was computed before the cone: every boundary px through the map."""
    w, h = calibration.image_size
    k = calibration.K
    centre_px = np.array([[k[0, 2], k[1, 2]]])
    boundary = cam.undistort_points(cam.image_boundary(w, h, 8), calibration)
    pts = cam.apply_homography(hom, np.concatenate([centre_px, boundary]))
    lonlat = tile_px_to_lonlat(TILE_ID, TILE_SIZE, pts, GSD_M)  # no turn of the globe near here
    ring = np.concatenate([lonlat[1:], lonlat[1:2]])
    d = ring - ring[0]
    if float(np.sum(d[:-1, 0] * d[1:, 1] - d[1:, 0] * d[:-1, 1])) < 0:
        ring = np.ascontiguousarray(ring[::-1])
    return (float(lonlat[0, 0]), float(lonlat[0, 1])), ring


@pytest.mark.parametrize(
    ("attitude_deg", "distortion"),
    [
        ((0.0, 0.0, 0.0), ()),
        ((3.0, -2.0, 140.0), (-0.2, 0.05, 0.001, -0.001, 0.0)),
        ((0.0, 20.0, 30.0), ()),
        ((-20.0, 5.0, 300.0), (-0.2, 0.05, 0.001, -0.001, 0.0)),
    ],
)
def test_a_frame_within_the_cone_keeps_its_footprint_bit_for_bit(
    attitude_deg: tuple[float, float, float], distortion: tuple[float, ...]
) -> None:
    """Nadir and 20 deg frames, with and without a lens: the same numbers as before, exactly."""
    base = _calibration()
    calibration = CameraCalibration(base.K, np.array(distortion or (0.0,) * 5), (640, 480))
    truth, _ = _true_map(calibration, attitude_deg)
    placed = footprint_lonlat(truth, TILE_ID, TILE_SIZE, calibration, GSD_M)
    assert placed is not None
    old_centre, old_ring = _old_footprint(truth, calibration)
    assert placed[0] == old_centre
    assert np.array_equal(placed[1], old_ring)


def test_a_map_that_is_not_a_finite_3x3_is_refused_by_name() -> None:
    hom = np.eye(3)
    hom[2, 0] = np.nan
    with pytest.raises(InvalidInputError, match="h_query_to_tile"):
        footprint_lonlat(hom, TILE_ID, TILE_SIZE, _calibration(), GSD_M)


def _pitched_map(pitch_deg: float, calibration: CameraCalibration) -> np.ndarray:
    """The exact map UNDISTORTED px -> px of a 0.5 m/px north-up 2048 px tile of a camera 100 m
    up, pitched ``pitch_deg`` forward (north) from nadir."""
    t = math.radians(pitch_deg)
    z = np.array([0.0, math.sin(t), -math.cos(t)])
    x = np.array([1.0, 0.0, 0.0])
    rotation = np.c_[x, np.cross(z, x), z]
    ground = calibration.K @ rotation.T @ np.c_[[1.0, 0, 0], [0, 1.0, 0], [0, 0, -100.0]]
    tile = np.array([[2.0, 0.0, 1024.0], [0.0, -2.0, 1024.0], [0.0, 0.0, 1.0]])
    return tile @ np.linalg.inv(ground)


@pytest.mark.parametrize("pitch_deg", [72.0, 74.0])
def test_a_centre_beyond_the_cut_is_no_centre(pitch_deg: float) -> None:
    """The principal point 72-74 deg off nadir lies within the 75-deg cone but beyond the
    straight cut the boundary gets (the query's own): it is on ground the query did not keep,
    so there is no centre (it lay outside its own footprint)."""
    calibration = CameraCalibration.pinhole(640, 480, 400.0)
    hom = _pitched_map(pitch_deg, calibration)
    assert footprint_lonlat(hom, TileId(17, 47.0, 8.0), (2048, 2048), calibration, 0.5) is None
    kept = footprint_lonlat(
        _pitched_map(60.0, calibration), TileId(17, 47.0, 8.0), (2048, 2048), calibration, 0.5
    )
    assert kept is not None  # 60 deg: the centre inside its footprint
