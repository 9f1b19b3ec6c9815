"""PreparedImage's coordinate maps: quarter turns, WORKING -> ORIGINAL rows, correspondences."""

import numpy as np
import pytest

from c3_matcher.dto import CameraCalibration
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage, correspondences, rotation_from_turned
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG


def test_turned_query_maps_engine_px_back_to_the_unturned_working_frame():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)  # (h, w) = (32, 48): not square
    valid = rng.random((32, 48)) > 0.5
    a = np.array([[2.5, 0.0, 0.75], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])  # engine -> working
    prepared = PreparedImage(image, valid, a, (120, 64))
    ys, xs = np.mgrid[0:32, 0:48]
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    working = prepared.to_working(pts)
    for deg in QUERY_ROTATIONS_DEG:
        turned = prepared.turned(deg)
        assert turned.working_size == prepared.working_size
        expected_size = (48, 32) if deg % 180 == 0 else (32, 48)
        assert turned.engine_size == expected_size
        # a working point lands on the turned engine pixel holding the same value, and back
        back = np.rint(turned.to_engine(working)).astype(int)
        assert np.allclose(turned.to_engine(working), back, atol=1e-9)
        assert np.array_equal(turned.image[back[:, 1], back[:, 0]], image[ys.ravel(), xs.ravel()])
        assert np.array_equal(turned.valid[back[:, 1], back[:, 0]], valid.ravel())
        assert np.allclose(turned.to_working(back), working, atol=1e-9)
    point = np.array([[47.0, 0.0]])  # top-right engine pixel of the unturned image
    m90 = rotation_from_turned(90, 48, 32)  # np.rot90 (counter-clockwise): it goes top-left
    assert np.allclose(m90 @ np.array([0.0, 0.0, 1.0]), [47.0, 0.0, 1.0])
    assert np.allclose(prepared.turned(90).to_engine(prepared.to_working(point)), [[0.0, 0.0]])


def test_a_turn_that_is_no_quarter_is_refused_and_zero_is_the_image_itself():
    image = PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (16, 16)
    )
    assert image.turned(0) is image
    with pytest.raises(ValueError, match="multiple of 90"):
        rotation_from_turned(45, 16, 16)


def test_correspondences_are_working_px_of_both_images():
    a = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])  # query engine -> working
    query = PreparedImage(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), bool), a, (16, 16))
    tile = PreparedImage(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), bool), np.eye(3), (8, 8))
    kq = np.array([[1.0, 1.0], [3.0, 2.0]], np.float32)
    kt = np.array([[5.0, 6.0], [7.0, 4.0]], np.float32)
    desc = np.zeros((2, 4), np.float32)
    fq = Features(kq, desc, np.ones(2, np.float32), (8, 8))
    ft = Features(kt, desc, np.ones(2, np.float32), (8, 8))
    raw = RawMatches(np.array([[1, 0], [0, 1]], np.int64), np.ones(2, np.float32))
    rows = correspondences(query, fq, tile, ft, raw)
    assert rows.dtype == np.float32
    assert np.allclose(rows, [[6.5, 4.5, 5.0, 6.0], [2.5, 2.5, 7.0, 4.0]])
    none = RawMatches(np.zeros((0, 2), np.int64), np.zeros(0, np.float32))
    assert correspondences(query, fq, tile, ft, none).shape == (0, 4)


@pytest.mark.parametrize(
    ("pairs", "said"),
    [
        ([[0, 0], [-1, 1]], "query keypoint -1, but the query has 2"),
        ([[0, 2]], "tile keypoint 2, but the tile has 2"),
    ],
)
def test_a_match_that_points_at_no_keypoint_is_refused_naming_it(pairs, said):
    """A matcher's -1 for "unmatched" paired the last keypoint (numpy counts from the end), and
    an index past the end was a bare IndexError: both are a ValueError naming the index."""
    image = PreparedImage(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), bool), np.eye(3), (8, 8))
    keypoints = np.array([[1.0, 1.0], [3.0, 2.0]], np.float32)
    features = Features(keypoints, np.zeros((2, 4), np.float32), np.ones(2, np.float32), (8, 8))
    raw = RawMatches(np.array(pairs, np.int64), np.ones(len(pairs), np.float32))
    with pytest.raises(ValueError, match=said):
        correspondences(image, features, image, features, raw)


def test_rows_in_original_px_move_only_the_query_point():
    rows = np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]], np.float32)
    tile = PreparedImage(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), bool), np.eye(3), (8, 8))
    assert np.array_equal(tile.in_original_px(rows), rows)  # a tile's WORKING px are its own
    shift = np.array(
        [[1.0, 0.0, -2.0], [0.0, 1.0, -3.0], [0.0, 0.0, 1.0]]
    )  # undistorted -> working
    calibration = CameraCalibration(
        K=np.array([[10.0, 0.0, 4.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]]),
        distortion=np.zeros(5),
        image_size=(8, 8),
    )
    query = PreparedImage(
        np.zeros((8, 8, 3), np.uint8),
        np.ones((8, 8), bool),
        np.eye(3),
        (8, 8),
        working_from_undistorted=shift,
        calibration=calibration,
    )
    moved = query.in_original_px(rows)
    assert moved.dtype == np.float32
    assert np.allclose(moved[:, :2], rows[:, :2] + [2.0, 3.0], atol=1e-5)  # no lens distortion
    assert np.array_equal(moved[:, 2:], rows[:, 2:])
