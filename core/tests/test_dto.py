"""DTOs: frozen, validated at construction, errors name the field."""

from __future__ import annotations

import dataclasses
import math
import uuid

import numpy as np
import pytest

from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    CandidateMatchSet,
    MatchResult,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import BytesTileHandle

TILE = TileId(18, 47.3769, 8.5417)


def cms(n: int, residual: float = 1.0, tile: TileId = TILE) -> CandidateMatchSet:
    return CandidateMatchSet(tile, n, np.zeros((n, 4), np.float32), 3, residual)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"zoom": 31, "lat": 0.0, "lon": 0.0}, "tile_id.zoom"),
        ({"zoom": 5, "lat": 91.0, "lon": 0.0}, "tile_id.lat"),
        ({"zoom": 5, "lat": 0.0, "lon": float("nan")}, "tile_id.lon"),
        ({"zoom": 5, "lat": 10**400, "lon": 0.0}, "tile_id.lat"),  # beyond a float
    ],
)
def test_tile_id_validation_names_field(kwargs, field):
    with pytest.raises(InvalidInputError, match=field):
        TileId(**kwargs)


def test_tile_id_parse_and_gsd():
    tile = TileId.parse("18,47.3769,8.5417")
    assert tile == TILE
    assert tile.web_mercator_gsd_m() == pytest.approx(
        0.5972 * math.cos(math.radians(47.3769)), rel=1e-3
    )
    with pytest.raises(InvalidInputError, match="ZOOM,LAT,LON"):
        TileId.parse("18,47")


def test_frame_validation():
    image = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(InvalidInputError, match="frame.image"):
        NavCameraFrame(uuid.uuid4(), image.astype(np.float32), 0)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="frame.image"):
        NavCameraFrame(uuid.uuid4(), np.zeros((32, 32, 4), np.uint8), 0)
    with pytest.raises(InvalidInputError, match="frame.height_above_ground_m"):
        NavCameraFrame(uuid.uuid4(), image, 0, height_above_ground_m=-5.0)
    with pytest.raises(InvalidInputError, match="attitude.pitch"):
        Attitude(0.0, 2.0, 0.0)
    with pytest.raises(InvalidInputError, match="frame.height_above_ground_m.*finite"):
        NavCameraFrame(uuid.uuid4(), image, 0, height_above_ground_m=10**400)
    with pytest.raises(InvalidInputError, match="attitude.roll"):
        Attitude.from_degrees(10**400, 0, 0)
    frame = NavCameraFrame(uuid.uuid4(), image, 0, Attitude.from_degrees(1, 2, 270), 120.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        frame.captured_at_ns = 5  # type: ignore[misc]


def test_calibration_validation_and_immutability():
    K = np.array([[800, 0, 320], [0, 800, 240], [0, 0, 1]], np.float64)
    with pytest.raises(InvalidInputError, match="calibration.distortion"):
        CameraCalibration(K, np.zeros(3), (640, 480))
    with pytest.raises(InvalidInputError, match="calibration.K"):
        CameraCalibration(K.astype(np.float32), np.zeros(4), (640, 480))  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="calibration.camera_to_body"):
        CameraCalibration(K, np.zeros(4), (640, 480), camera_to_body=np.ones((3, 3)))
    cal = CameraCalibration(K, np.zeros(5), (640, 480))
    K[0, 0] = 1.0  # the DTO holds its own read-only copy
    assert cal.K[0, 0] == 800
    with pytest.raises(ValueError, match="read-only"):
        cal.K[0, 0] = 2.0


def test_rerank_validation():
    handle = BytesTileHandle(b"x")
    assert RerankResult(uuid.uuid4(), []).candidates == ()  # no tile proposed: see the pipeline
    with pytest.raises(InvalidInputError, match="rerank_result.candidates"):
        RerankResult(uuid.uuid4(), None)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="candidate.tile_pixels_handle"):
        RerankCandidate(TILE, 0.5, object())  # type: ignore[arg-type]
    cand = RerankCandidate(TILE, 0.5, handle)
    assert cand.ground_sample_distance_m() == pytest.approx(TILE.web_mercator_gsd_m())
    assert RerankCandidate(TILE, 0.5, handle, 0.25).ground_sample_distance_m() == 0.25


def test_candidate_match_set_inv5():
    with pytest.raises(InvalidInputError, match="inlier_correspondences"):
        CandidateMatchSet(TILE, 5, np.zeros((4, 4), np.float32), 0, 1.0)
    with pytest.raises(InvalidInputError, match="inlier_correspondences"):
        CandidateMatchSet(TILE, 4, np.zeros((4, 4), np.float64), 0, 1.0)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="per_candidate_residual_px"):
        CandidateMatchSet(TILE, 4, np.zeros((4, 4), np.float32), 0, -1.0)


def _result(per, **overrides):  # type: ignore[no-untyped-def]
    fields = dict(
        frame_id=uuid.uuid4(),
        per_candidate=per,
        best_candidate_idx=0,
        reprojection_residual_px=per[0].per_candidate_residual_px,
        matched_at=1,
        matcher_label="x",
        candidates_input=3,
        candidates_dropped=3 - len(per),
    )
    fields.update(overrides)
    return MatchResult(**fields)


def test_match_result_invariants():
    per = (cms(120, 1.1), cms(120, 1.4), cms(80, 1.0))
    assert _result(per).best.inlier_count == 120
    with pytest.raises(InvalidInputError, match="per_candidate: must be sorted"):
        _result((per[1], per[0], per[2]))
    with pytest.raises(InvalidInputError, match="best_candidate_idx: must be 0"):
        _result(per, best_candidate_idx=1)
    with pytest.raises(InvalidInputError, match="reprojection_residual_px: must equal"):
        _result(per, reprojection_residual_px=1.4)
    with pytest.raises(InvalidInputError, match="candidates_dropped: must equal"):
        _result(per, candidates_dropped=1)
    with pytest.raises(InvalidInputError, match="survivors > 2 input candidates"):
        _result(per, candidates_input=2, candidates_dropped=-1)


@pytest.mark.parametrize(
    ("size", "reason"),
    [
        (640, "expected (width, height), got int"),  # not a pair at all
        ("640x480", "expected (width, height), got str"),
        ((640, 480, 3), "expected (width, height)"),
        ((True, True), "width must be an int, got True"),  # a bool is no size
        ((640.0, 480), "width must be an int, got 640.0"),
        ((640, 0), "height must be > 0, got 0"),
    ],
)
def test_calibration_image_size_refusals_name_the_field(size, reason):
    K = np.array([[800, 0, 320], [0, 800, 240], [0, 0, 1]], np.float64)
    with pytest.raises(InvalidInputError, match="calibration.image_size") as info:
        CameraCalibration(K, np.zeros(0), size)
    assert reason in str(info.value)


def test_calibration_image_size_takes_numpy_ints_as_ints():
    K = np.array([[800, 0, 320], [0, 800, 240], [0, 0, 1]], np.float64)
    cal = CameraCalibration(K, np.zeros(0), tuple(np.array([640, 480])))  # type: ignore[arg-type]
    assert cal.image_size == (640, 480) and all(type(s) is int for s in cal.image_size)


@pytest.mark.parametrize("candidates", [None, 3, "ab"])
def test_rerank_candidates_that_are_no_sequence_are_named(candidates):
    with pytest.raises(InvalidInputError, match="rerank_result.candidates: expected a sequence"):
        RerankResult(uuid.uuid4(), candidates)  # type: ignore[arg-type]
