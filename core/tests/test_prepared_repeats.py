"""A match that pairs one query keypoint more than once is refused where its correspondences are
assembled (each pair would count as an inlier of its own): the candidate is dropped under the
backend's match phase, in flight as at start-up."""

from __future__ import annotations

import uuid

import numpy as np
import pytest

from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import PreparedImage, correspondences
from c3_matcher.testing.fakes import ScriptedCandidate, make_frame, make_rerank, scripted_pipeline
from c3_matcher.testing.scripted import MarkedRansac, ScriptedBackend

from .test_probe_moved_copy import TileSideNearest


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
    once = RawMatches(np.array([[0, 2], [3, 2], [4, 1]], np.int64), np.ones(3, np.float32))
    rows = correspondences(_image(), query, _image(), tile, once)  # a tile keypoint twice: kept
    assert rows.tolist() == [[0, 0, 2, 2], [3, 3, 2, 2], [4, 4, 1, 1]]


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
