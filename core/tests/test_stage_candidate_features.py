"""The candidate-features stage: stored, cached or extracted features, the phase of a failure,
and the feature request a backend declares (its keypoint budget)."""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import RerankCandidate
from c3_matcher.features import Features
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.protocols import StoredFeaturesBackend
from c3_matcher.stages.candidate_features import CandidateFeatures, feature_request
from c3_matcher.stages.extract import Extraction
from c3_matcher.stages.failure import CandidateStepError
from c3_matcher.testing import (
    FakeBackend,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    ScriptedCandidate,
    make_rerank,
)
from c3_matcher.tile_cache import TileFeatureCache
from c3_matcher.tiles import BytesTileHandle

SHA = "ab" * 32


class BudgetBackend(FakeBackend):
    """A FakeBackend that declares a keypoint budget and its extractor engine."""

    max_keypoints = 512
    extractor_sha256: str | None = SHA

    def provenance(self) -> dict[str, Any]:
        return {"provider": "FakeExecutionProvider", "engines": {"extractor": {"file_sha256": SHA}}}


class StoredHandle(BytesTileHandle):
    """A tile handle whose store holds features (or raises ``error``)."""

    def __init__(self, data: bytes, features: Features | None, error: Exception | None = None):
        super().__init__(data, "stored")
        self.features, self.error, self.requests = features, error, []

    def stored_features(self, request: Any) -> Features | None:
        self.requests.append(request)
        if self.error is not None:
            raise self.error
        return self.features


class Recorder:
    """Stands in for the frame recorder: the stage only reports stored-feature failures."""

    frame_id = "frame"

    def __init__(self) -> None:
        self.failures: list[tuple[Any, str]] = []

    def stored_features_failed(self, tile_id: Any, exc: Exception) -> None:
        self.failures.append((tile_id, str(exc)))


def _backend(cls: type[FakeBackend] = FakeBackend, script=()) -> FakeBackend:
    return cls(FakeInferenceRuntime(script), FakeLightGlueRuntime(script))


def _source(backend: FakeBackend, cache: int = 0, stored: bool = True) -> CandidateFeatures:
    pre = FramePreprocessor(backend.input_rule)
    request = feature_request(backend, pre)
    return CandidateFeatures(Extraction(backend), pre, TileFeatureCache(cache), request, stored)


def _candidate(script: list[ScriptedCandidate] | None = None) -> RerankCandidate:
    return make_rerank(uuid.UUID(int=1), script or [ScriptedCandidate()]).candidates[0]


def test_the_request_carries_the_declared_budget_rule_erosion_and_provider():
    backend = _backend(BudgetBackend)
    assert isinstance(backend, StoredFeaturesBackend)
    pre = FramePreprocessor(backend.input_rule, border_erode_px=3, photometric="grey")
    request = feature_request(backend, pre)
    assert request is not None
    assert (request.extractor_sha256, request.max_keypoints) == (SHA, 512)
    assert (request.multiple, request.max_long_side) == (16, 64)
    assert (request.border_erode_px, request.photometric) == (3, "grey")


def test_no_request_without_a_declared_budget_or_a_declared_extractor():
    plain = _backend()
    assert not isinstance(plain, StoredFeaturesBackend)
    assert feature_request(plain, FramePreprocessor(plain.input_rule)) is None

    class Undeclared(FakeBackend):  # a budget, and a sha in its provenance, but no declaration
        max_keypoints = 512

        def provenance(self) -> dict[str, Any]:
            return {"provider": "x", "engines": {"extractor": {"file_sha256": SHA}}}

    class Unnamed(BudgetBackend):
        extractor_sha256 = None

    class NoBudget(BudgetBackend):
        max_keypoints = 0

    assert not isinstance(_backend(Undeclared), StoredFeaturesBackend)
    for cls in (Undeclared, Unnamed, NoBudget):
        backend = _backend(cls)
        assert feature_request(backend, FramePreprocessor(backend.input_rule)) is None
    source = _source(plain)
    assert source.request is None and not source.use_stored


def test_extracted_then_cached_with_their_timings():
    source = _source(_backend(), cache=4)
    candidate = _candidate()
    first_timings: dict[str, float] = {}
    first = source.fetch(candidate, Recorder(), first_timings)  # type: ignore[arg-type]
    assert first.source == "extracted" and len(first.features) == 8
    assert list(first_timings) == ["decode", "preprocess", "extract"]
    again_timings: dict[str, float] = {}
    again = source.fetch(candidate, Recorder(), again_timings)  # type: ignore[arg-type]
    assert again.source == "cached" and again.features is first.features
    assert again_timings == {}


def test_stored_features_are_served_when_the_tile_fits_the_rule():
    backend = _backend(BudgetBackend)
    plain = _candidate()
    features = Features(
        np.zeros((3, 2), np.float32), np.zeros((3, 4), np.float32), np.ones(3, np.float32), (64, 64)
    )
    handle = StoredHandle(plain.tile_pixels_handle.encoded().tobytes(), features)
    candidate = RerankCandidate(plain.tile_id, plain.score, handle, gsd_m_per_px=0.3)
    timings: dict[str, float] = {}
    got = _source(backend).fetch(candidate, Recorder(), timings)  # type: ignore[arg-type]
    assert got.source == "stored" and got.features is features
    assert got.image.working_size == (64, 64) and list(timings) == ["assemble"]
    assert handle.requests[0].max_keypoints == 512
    off = _source(backend, stored=False).fetch(candidate, Recorder(), {})  # type: ignore[arg-type]
    assert off.source == "extracted"


def test_a_failing_store_falls_back_to_extraction_and_is_reported():
    plain = _candidate()
    handle = StoredHandle(plain.tile_pixels_handle.encoded().tobytes(), None, OSError("locked"))
    candidate = RerankCandidate(plain.tile_id, plain.score, handle, gsd_m_per_px=0.3)
    recorder = Recorder()
    got = _source(_backend(BudgetBackend)).fetch(candidate, recorder, {})  # type: ignore[arg-type]
    assert got.source == "extracted"
    assert recorder.failures == [(candidate.tile_id, "locked")]


@pytest.mark.parametrize(
    ("scripted", "phase"),
    [
        (ScriptedCandidate(fail_decode=True), "tile_decode"),
        (ScriptedCandidate(fail_extract=True), "disk_forward"),
    ],
)
def test_a_failure_names_its_phase_and_source(scripted, phase):
    backend = _backend(script=[scripted])
    with pytest.raises(CandidateStepError) as failed:
        _source(backend).fetch(_candidate([scripted]), Recorder(), {})  # type: ignore[arg-type]
    assert (failed.value.phase, failed.value.source) == (phase, "extracted")
    assert isinstance(failed.value.cause, (ValueError, RuntimeError))


class RewrittenWhileDecoded(BytesTileHandle):
    """A tile file rewritten between the read its cache key comes from and the read decoded."""

    def __init__(self, first: bytes, then: bytes) -> None:
        super().__init__(first, "rewritten")
        self.then = then

    def decode(self) -> np.ndarray:
        self._data = self.then
        return super().decode()


def test_a_tile_rewritten_while_decoded_is_not_cached_under_its_old_bytes():
    import dataclasses

    two = make_rerank(uuid.UUID(int=2), [ScriptedCandidate(), ScriptedCandidate()]).candidates
    first, then = (bytes(c.tile_pixels_handle.encoded()) for c in two)
    source = _source(_backend(), cache=4)
    rewritten = dataclasses.replace(two[0], tile_pixels_handle=RewrittenWhileDecoded(first, then))
    assert source.fetch(rewritten, Recorder(), {}).source == "extracted"  # type: ignore[arg-type]
    again = dataclasses.replace(two[0], tile_pixels_handle=BytesTileHandle(first))
    assert source.fetch(again, Recorder(), {}).source == "extracted"  # type: ignore[arg-type]
    assert source.fetch(again, Recorder(), {}).source == "cached"  # type: ignore[arg-type]


def test_stored_features_off_their_window_are_not_served_but_extracted_instead():
    """A store's features with a keypoint far off the window (a set built by a backend that
    forgot a scale) are checked as an extraction is: reported, and the tile extracted."""
    backend = _backend(BudgetBackend)
    plain = _candidate()
    keypoints = np.array([[4116.0, 30.0], [10.0, 20.0]], np.float32)  # x 4116 on a 64 px window
    off = Features(keypoints, np.zeros((2, 4), np.float32), np.ones(2, np.float32), (64, 64))
    handle = StoredHandle(plain.tile_pixels_handle.encoded().tobytes(), off)
    candidate = RerankCandidate(plain.tile_id, plain.score, handle, gsd_m_per_px=0.3)
    recorder = Recorder()
    got = _source(backend).fetch(candidate, recorder, {})  # type: ignore[arg-type]
    assert got.source == "extracted" and got.features is not off
    assert [tile for tile, _ in recorder.failures] == [plain.tile_id]
    assert "1 keypoint(s) outside the 64x64 px" in recorder.failures[0][1]
