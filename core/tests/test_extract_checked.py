"""A backend's features are checked on every image the core gives it, not only at start-up: a
backend that forgets a scale past some image size (its keypoints off the image) or returns
something other than ``Features`` fails that extraction, naming it, as a NaN keypoint does,
instead of reaching RANSAC as correspondences nowhere on the images (a confident, wrong fix) or
being cached for the next frames. A real ORB backend on the demo frame and its real tiles, real
RANSAC."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.demo import demo_inputs
from c3_matcher.errors import InsufficientInliersError, InvalidInputError, MatcherBackboneError
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.probe import engine_startup_probe
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.stages.extract import checked_features
from c3_matcher.testing import FakeClock, InMemoryFdr

from .test_contract_kit import OpenCvBackend

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
TRUE = 1  # the demo frame's true tile: the second candidate


class Faulty:
    """ORB + cross-checked brute force (the plugin guide's backend), with one fault from
    extract's call ``from_call`` on (1: the query, then the tiles): ``scale``, keypoints of
    images over 300 px left at twice their size (detected upsampled, never scaled back);
    ``none_at``, the calls that return None."""

    extract_phase, match_phase = "orb_detect", "bf_hamming"

    def __init__(
        self, *, scale: bool = False, from_call: int = 1, none_at: tuple[int, ...] = ()
    ) -> None:
        import cv2

        self._inner = OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb")
        self.label, self.input_rule = "orb", self._inner.input_rule
        self.scale, self.from_call, self.none_at, self.calls = scale, from_call, none_at, 0

    def extract(self, image: PreparedImage) -> Features | None:
        self.calls += 1
        if self.calls in self.none_at:
            return None
        features = self._inner.extract(image)
        if self.scale and self.calls >= self.from_call and max(features.image_size) > 300:
            return dataclasses.replace(features, keypoints=features.keypoints * 2)
        return features

    def match(self, query: Features, tile: Features) -> RawMatches:
        return self._inner.match(query, tile)

    def provenance(self) -> dict[str, Any]:
        return self._inner.provenance()


def _matcher(backend: Any, fdr: InMemoryFdr) -> PipelineMatcher:
    clock = FakeClock()
    settings = PipelineSettings(tile_cache_size=3)
    health = RollingHealthWindow(clock, settings.min_inliers_threshold)
    ransac = OpenCvRansacFilter()
    return PipelineMatcher(backend, ransac, fdr, health, clock, settings)


def test_the_plain_backend_finds_the_true_tile() -> None:
    """The control: the same backend without its fault matches the demo frame."""
    frame, rerank, calibration = demo_inputs(DEMO)
    result = _matcher(Faulty(), InMemoryFdr()).match(frame, rerank, calibration)
    assert result.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert result.per_candidate[0].inlier_count >= 60


def test_query_keypoints_off_the_frame_fail_the_frame_though_the_probe_passed() -> None:
    """The start-up probe's images are under 300 px: it passes. In flight the query's
    keypoints lie off the frame: a backbone error in the query's extract naming them, no fix."""
    backend = Faulty(scale=True)
    engine_startup_probe(backend)  # type: ignore[arg-type]
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    with pytest.raises(MatcherBackboneError) as failed:
        _matcher(backend, fdr).match(frame, rerank, calibration)
    assert failed.value.phase == "query_extract"
    said = str(failed.value)
    assert "InvalidInputError: features.keypoints: " in said and "keypoint(s) outside the" in said
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert record["phase"] == "query_extract" and "keypoint(s) outside the" in record["error"]


def test_tile_keypoints_off_the_tile_drop_each_tile_naming_the_extract_phase() -> None:
    """The query is right, every tile's keypoints are off the tile: each tile is dropped as a
    backbone error of the backend's extract phase, as a NaN keypoint is; no fix."""
    backend = Faulty(scale=True, from_call=2)
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    with pytest.raises(InsufficientInliersError):
        _matcher(backend, fdr).match(frame, rerank, calibration)
    errors = fdr.of_kind("matcher.backbone_error")
    assert [e["phase"] for e in errors] == ["orb_detect"] * 3
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    reasons = [d["reason"] for d in record["dropped"]]
    assert len(reasons) == 3
    start = "backbone error in orb_detect: InvalidInputError: features.keypoints: "
    assert all(r.startswith(start) and "outside the 512x512 px image" in r for r in reasons)


def test_a_query_extracted_as_none_fails_the_frame_in_its_extract() -> None:
    """None for the query frame's features: the frame cannot be processed, a backbone error of
    the query's extract naming what extract returned, not a low-inlier frame blaming match."""
    frame, rerank, calibration = demo_inputs(DEMO)
    with pytest.raises(MatcherBackboneError) as failed:
        _matcher(Faulty(none_at=(1,)), InMemoryFdr()).match(frame, rerank, calibration)
    assert failed.value.phase == "query_extract"
    assert "features: extract returned NoneType, not Features" in str(failed.value)


def test_a_tile_extracted_as_none_drops_that_tile_once_and_is_not_cached() -> None:
    """The true tile's extraction returns None (extract's third call: the query, the first
    candidate, then it): it is dropped in the extract phase, naming why, and the frame finds no
    fix; the next frame extracts the tile again and matches it."""
    backend = Faulty(none_at=(3,))
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    matcher = _matcher(backend, fdr)
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    (dropped,) = [d for d in record["dropped"] if d["candidate_index"] == TRUE]
    said = "backbone error in orb_detect: InvalidInputError: features: extract returned NoneType"
    assert dropped["reason"].startswith(said)
    again = matcher.match(frame, rerank, calibration)
    assert again.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert again.diagnostics["candidate_features"][TRUE] == "extracted"


@pytest.mark.parametrize(
    ("keypoints", "off"),
    [
        ([[0.0, 0.0], [99.0, 49.0]], 0),
        ([[-1.5, 0.0], [100.5, 50.5]], 0),  # sub-pixel refinement a pixel past the edge
        ([[-1.6, 0.0]], 1),
        ([[10.0, 51.0], [200.0, 10.0]], 2),
    ],
)
def test_the_bounds_are_the_image_and_a_pixel(keypoints: list[list[float]], off: int) -> None:
    kp = np.array(keypoints, np.float32)
    n = len(kp)
    features = Features(kp, np.zeros((n, 32), np.uint8), np.ones(n, np.float32), (100, 50))
    if not off:
        assert checked_features(features, (100, 50)) is features
        return
    with pytest.raises(InvalidInputError) as refused:
        checked_features(features, (100, 50))
    assert refused.value.field == "features.keypoints"
    assert refused.value.reason.startswith(f"{off} keypoint(s) outside the 100x50 px image")
