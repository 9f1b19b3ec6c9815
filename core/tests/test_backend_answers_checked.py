"""What a backend's ``extract`` and ``match`` return is checked before the core uses or caches
it: an extraction with more keypoints than the backend's budget (its ``max_keypoints``, else
the core's ceiling) is refused naming both; a tile whose descriptors differ from the query's in
dtype or width fails the backend's extract phase naming both arrays and the backbone, before
``match``; a match that returns anything but ``RawMatches`` is named so; a refused or unmatched
tile leaves the tile cache. The kit's doubles, made to misbehave."""

from __future__ import annotations

import dataclasses
import uuid
from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import TileId
from c3_matcher.errors import InsufficientInliersError, InvalidInputError, MatcherBackboneError
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.candidate_features import CandidateFeatures
from c3_matcher.stages.extract import KEYPOINT_CEILING, extract_checked, extraction_budget
from c3_matcher.stages.failure import CandidateStepError
from c3_matcher.stages.matching import check_descriptors_fit
from c3_matcher.stages.outcomes import TileFeatures
from c3_matcher.stages.query import QueryView
from c3_matcher.stages.verify import Verifier, best_turn
from c3_matcher.testing import (
    FakeBackend,
    FakeInferenceRuntime,
    FakeLightGlueRuntime,
    FakeRansacFilter,
    InMemoryFdr,
    ScriptedCandidate,
    SequenceRansacFilter,
    make_frame,
    make_rerank,
    scripted_pipeline,
)
from c3_matcher.tile_cache import TileFeatureCache

TILE = TileId(18, 47.0, 8.5)


def _features(n: int, width: int = 4, dtype: Any = np.float32) -> Features:
    kp = np.stack([np.arange(n) % 16, np.arange(n) // 16], axis=1).astype(np.float32)
    return Features(kp, np.zeros((n, width), dtype), np.ones(n, np.float32), (16, 16))


def _image(side: int = 16) -> PreparedImage:
    return PreparedImage(
        np.full((side, side, 3), 1, np.uint8), np.ones((side, side), bool), np.eye(3), (side, side)
    )


def _backend(cls: type[FakeBackend] = FakeBackend) -> FakeBackend:
    return cls(FakeInferenceRuntime(), FakeLightGlueRuntime())


class Answers(FakeBackend):
    """A FakeBackend whose ``match`` returns ``answer`` (or raises it, an exception)."""

    answer: Any = None

    def match(self, query: Features, tile: Features) -> Any:
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


class Forgotten:
    """Counts the calls of a tile's ``forget``."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self) -> None:
        self.calls += 1


def _turn(backend: Any, tile: Features, ransac: Any = None) -> tuple[Forgotten, Any]:
    """``best_turn`` of a 4-keypoint float32 (4 wide) query with ``tile`` (cached): how often
    it forgot the tile, and the verdict or the ``CandidateStepError`` it raised."""
    forgotten = Forgotten()
    cached = TileFeatures("cached", _image(), tile, forgotten)
    verifier = Verifier(ransac or SequenceRansacFilter([(4, 1.0)]), 3.0, None)
    views = [QueryView(0, _image(), _features(4))]
    try:
        return forgotten, best_turn(backend, verifier, views, TILE, cached, {})
    except CandidateStepError as failed:
        return forgotten, failed


@pytest.mark.parametrize(("width", "dtype"), [(8, np.uint8), (4, np.float32), (4, np.uint8)])
def test_descriptors_unlike_the_querys_are_refused_naming_both(width: int, dtype: Any) -> None:
    with pytest.raises(InvalidInputError) as refused:
        check_descriptors_fit(_features(5, 8), _features(3, width, dtype), "disk_lightglue")
    assert refused.value.field == "features.descriptors"
    said = f"the tile's descriptors (3, {width}) {np.dtype(dtype)} do not fit the query's (5, 8) "
    assert refused.value.reason.startswith(f"{said}float32 (backbone disk_lightglue)")


def test_descriptors_of_one_dtype_and_width_fit_with_or_without_keypoints() -> None:
    check_descriptors_fit(_features(5, 8), _features(3, 8), "x")
    check_descriptors_fit(_features(5, 32, np.uint8), _features(0, 32, np.uint8), "x")
    with pytest.raises(InvalidInputError):  # an empty tile still has its descriptors' width
        check_descriptors_fit(_features(5, 32, np.uint8), _features(0, 0, np.float32), "x")


def test_a_tile_unlike_the_query_fails_the_extract_phase_before_match_and_is_forgotten() -> None:
    backend = _backend(Answers)
    forgotten, failed = _turn(backend, _features(4, 16, np.uint8))
    assert isinstance(failed, CandidateStepError)
    assert (failed.phase, failed.source) == ("disk_forward", "cached")
    assert "(backbone fake_backend)" in str(failed.cause)
    assert forgotten.calls == 1  # and match never ran: Answers would have returned None


@pytest.mark.parametrize("answer", [None, np.zeros((2, 2), np.int64), ((0, 0),), [], "pairs"])
def test_a_match_that_returns_no_raw_matches_is_named_and_its_tile_forgotten(answer: Any) -> None:
    backend = _backend(Answers)
    backend.answer = answer  # type: ignore[attr-defined]
    forgotten, failed = _turn(backend, _features(4))
    assert isinstance(failed, CandidateStepError) and failed.phase == "lightglue_match"
    assert isinstance(failed.cause, InvalidInputError) and failed.cause.field == "raw_matches"
    kind = type(answer).__name__
    assert failed.cause.reason == f"match returned {kind}, not RawMatches (backbone fake_backend)"
    assert forgotten.calls == 1


def test_a_raising_match_forgets_its_tile_and_a_failing_ransac_keeps_it() -> None:
    backend = _backend(Answers)
    backend.answer = RuntimeError("matcher down")  # type: ignore[attr-defined]
    forgotten, failed = _turn(backend, _features(4))
    assert isinstance(failed, CandidateStepError) and failed.phase == "lightglue_match"
    assert forgotten.calls == 1

    class Broken(SequenceRansacFilter):
        def filter(self, rows: Any, threshold_px: float) -> Any:
            raise ValueError("ransac down")

    idx = np.arange(4, dtype=np.int64)
    backend.answer = RawMatches(np.stack([idx, idx], 1), np.ones(4, np.float32))  # type: ignore[attr-defined]
    forgotten, failed = _turn(backend, _features(4), Broken([(1, 1.0)]))
    assert isinstance(failed, CandidateStepError) and failed.phase == "ransac"
    assert forgotten.calls == 0  # the features were matched: the tile is not at fault
    forgotten, verdict = _turn(backend, _features(4))
    assert verdict.raw_matches == 4 and forgotten.calls == 0


def test_a_forgotten_tile_leaves_the_cache_and_is_extracted_again() -> None:
    backend = _backend()
    pre = FramePreprocessor(backend.input_rule)
    source = CandidateFeatures(backend, pre, TileFeatureCache(4), None, False)
    candidate = make_rerank(uuid.UUID(int=1), [ScriptedCandidate()]).candidates[0]
    first = source.fetch(candidate, None, {})  # type: ignore[arg-type]
    cached = source.fetch(candidate, None, {})  # type: ignore[arg-type]
    assert (first.source, cached.source, len(source.cache)) == ("extracted", "cached", 1)
    cached.forget()
    assert len(source.cache) == 0
    again = source.fetch(candidate, None, {})  # type: ignore[arg-type]
    assert again.source == "extracted"
    again.forget()
    again.forget()  # forgetting twice, or a tile the cache no longer holds, is no fault
    off = CandidateFeatures(backend, pre, TileFeatureCache(0), None, False)
    off.fetch(candidate, None, {}).forget()  # type: ignore[arg-type]


class Budgeted(FakeBackend):
    """A FakeBackend (8 keypoints on a marked image) that declares ``max_keypoints``."""

    max_keypoints: Any = 8


class Many(FakeBackend):
    """A FakeBackend that declares no budget and extracts ``n`` keypoints."""

    n = KEYPOINT_CEILING

    def extract(self, image: PreparedImage) -> Features:
        w, h = image.engine_size
        xy = np.stack([np.arange(self.n) % w, np.arange(self.n) // w % h], 1)
        zeros = np.zeros((self.n, 4), np.float32)
        return Features(xy.astype(np.float32), zeros, np.ones(self.n, np.float32), (w, h))


def test_an_extraction_over_the_declared_budget_is_refused_naming_count_and_budget() -> None:
    backend = _backend(Budgeted)
    assert len(extract_checked(backend, _image(64))) == 8  # at the budget: taken
    backend.max_keypoints = 7  # type: ignore[attr-defined]
    with pytest.raises(InvalidInputError) as refused:
        extract_checked(backend, _image(64))
    assert refused.value.field == "features.keypoints"
    assert refused.value.reason == (
        "8 keypoints on the 64x64 px image, more than the 7 backbone fake_backend declares "
        "(max_keypoints)"
    )


def test_a_backend_without_a_budget_is_held_to_the_core_ceiling() -> None:
    backend = _backend(Many)
    assert len(extract_checked(backend, _image(256))) == KEYPOINT_CEILING
    backend.n = KEYPOINT_CEILING + 1  # type: ignore[attr-defined]
    with pytest.raises(InvalidInputError) as refused:
        extract_checked(backend, _image(256))
    assert refused.value.reason.startswith(
        f"{KEYPOINT_CEILING + 1} keypoints on the 256x256 px image, more than the core's "
        f"ceiling of {KEYPOINT_CEILING} for a backbone that declares no keypoint budget"
    )


@pytest.mark.parametrize("declared", [0, -5, True, "8", None, 8.0])
def test_a_declared_budget_that_is_no_positive_int_gives_the_ceiling(declared: Any) -> None:
    backend = _backend(Budgeted)
    backend.max_keypoints = declared  # type: ignore[attr-defined]
    assert extraction_budget(backend)[0] == KEYPOINT_CEILING


def test_over_budget_the_query_fails_its_frame_and_a_tile_drops_in_extract() -> None:
    """In flight: a query over the budget is a backbone error of the frame's query extract; a
    tile over it (the query within) drops that candidate in the backend's extract phase."""

    class TilesOver(Budgeted):
        def extract(self, image: PreparedImage) -> Features:
            features = super().extract(image)
            if image.calibration is not None:  # the query
                return dataclasses.replace(
                    features,
                    keypoints=features.keypoints[:4].copy(),
                    descriptors=features.descriptors[:4].copy(),
                    keypoint_scores=features.keypoint_scores[:4].copy(),
                )
            return features

    script = [ScriptedCandidate()]
    frame, calibration = make_frame(uuid.UUID(int=3))
    rerank = make_rerank(frame.frame_id, script)
    for cls, fails in ((Budgeted, MatcherBackboneError), (TilesOver, InsufficientInliersError)):
        backend = cls(FakeInferenceRuntime(script), FakeLightGlueRuntime(script))
        backend.max_keypoints = 5  # type: ignore[attr-defined]
        fdr = InMemoryFdr()
        matcher = scripted_pipeline(backend, FakeRansacFilter(script), fdr, PipelineSettings())
        with pytest.raises(fails):
            matcher.match(frame, rerank, calibration)
        (record,) = fdr.of_kind("matcher.backbone_error")
        phase = "query_extract" if cls is Budgeted else "disk_forward"
        assert record["phase"] == phase
        assert (
            "8 keypoints on the" in record["error"]
            and "more than the 5 backbone" in record["error"]
        )


def test_the_refine_pass_names_a_match_that_returns_no_raw_matches() -> None:
    """The refine pass's match is checked as a candidate's is: the first pass stands, and the
    record says what match returned."""
    from .test_stage_refine import _first, _run, _setup

    backend, pre, query = _setup()
    first = _first(backend, pre, np.eye(3))
    backend.match = lambda q, t: None  # type: ignore[method-assign]
    survivors, record, reports = _run(backend, pre, query, first)
    said = "raw_matches: match returned NoneType, not RawMatches (backbone fake_backend)"
    assert survivors == [first] and record.reason == f"InvalidInputError: {said}"
    assert reports.failed == [said]
