"""A match that pairs one query keypoint, or one tile keypoint, more than once is refused where
its correspondences are assembled (each pair would count as an inlier of its own): the candidate
is dropped under the backend's match phase, in flight as at start-up."""

from __future__ import annotations

import uuid
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.demo import demo_inputs
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import PreparedImage, correspondences
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.testing.fakes import ScriptedCandidate, make_frame, make_rerank, scripted_pipeline
from c3_matcher.testing.scripted import MarkedRansac, ScriptedBackend

from .test_contract_kit import OpenCvBackend
from .test_probe_moved_copy import TileSideNearest

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"


def _features(n: int) -> Features:
    kp = np.stack([np.arange(n), np.arange(n)], 1).astype(np.float32)
    return Features(kp, np.eye(n, 8, dtype=np.float32), np.ones(n, np.float32), (16, 16))


def _image() -> PreparedImage:
    return PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (16, 16)
    )


def test_a_query_keypoint_paired_twice_is_refused_naming_it():
    query, tile = _features(5), _features(5)
    twice = RawMatches(np.array([[0, 0], [3, 1], [3, 2]], np.int64), np.ones(3, np.float32))
    with pytest.raises(ValueError, match="pairs query keypoint 3 2 times"):
        correspondences(_image(), query, _image(), tile, twice)
    once = RawMatches(np.array([[0, 2], [3, 0], [4, 1]], np.int64), np.ones(3, np.float32))
    rows = correspondences(_image(), query, _image(), tile, once)
    assert rows.tolist() == [[0, 0, 2, 2], [3, 3, 0, 0], [4, 4, 1, 1]]


def test_a_tile_keypoint_paired_twice_is_refused_naming_it():
    """A many-to-one matcher (brute force without a cross-check) pairs one tile keypoint with
    several query keypoints: each pair would count as an inlier of its own."""
    query, tile = _features(5), _features(5)
    many = RawMatches(np.array([[0, 2], [3, 2], [4, 2], [1, 1]], np.int64), np.ones(4, np.float32))
    with pytest.raises(ValueError, match="pairs tile keypoint 2 3 times"):
        correspondences(_image(), query, _image(), tile, many)


def test_brute_force_without_a_cross_check_drops_every_demo_tile_under_the_match_phase():
    """ORB + brute force without a cross-check on the demo frame and its real tiles: each tile
    keypoint the frame's keypoints crowd onto is refused, naming the tile keypoint and the
    phase, instead of a fix whose inlier count counts it many times."""
    backend = OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb", cross_check=False)
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    matcher = scripted_pipeline(backend, OpenCvRansacFilter(), fdr, PipelineSettings())
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    reasons = [d["reason"] for d in record["dropped"]]
    start = "backbone error in cv_match: ValueError: the matcher's output pairs tile keypoint "
    assert len(reasons) == 3 and all(r.startswith(start) for r in reasons), reasons


def test_in_flight_the_candidate_is_dropped_under_the_match_phase():
    script = [ScriptedCandidate(120)]
    backend = ScriptedBackend(TileSideNearest(), script)
    fdr = InMemoryFdr()
    matcher = scripted_pipeline(backend, MarkedRansac(script, backend), fdr, PipelineSettings())
    frame, calibration = make_frame(uuid.UUID(int=5), 256)
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, make_rerank(frame.frame_id, script, 256), calibration)
    (error,) = fdr.of_kind("matcher.backbone_error")
    assert error["phase"] == "bf_hamming" and "times (each query keypoint" in error["error"]
