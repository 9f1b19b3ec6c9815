"""What a backend's ``extract`` and ``match`` return is checked before the core uses or caches
it: an extraction with more keypoints than the backend's budget (its ``max_keypoints``, else
the core's ceiling) keeps its best by score, said once per matcher; a tile whose descriptors
differ from the query's in dtype or width fails the backend's extract phase naming both arrays
and the backbone, before ``match`` (an image without keypoints fits any); a match that returns
anything but ``RawMatches`` is named so; a refused or unmatched tile leaves the tile cache. The
kit's doubles, made to misbehave."""

from __future__ import annotations

import io
import json
import uuid
from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features, RawMatches
from c3_matcher.logs import configure_logging
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.stages.candidate_features import CandidateFeatures
from c3_matcher.stages.extract import (
    KEYPOINT_BUDGET_UNREAD,
    KEYPOINT_CEILING,
    KEYPOINTS_CUT,
    Extraction,
    backend_budget,
    cut_to_budget,
    extract_checked,
    extraction_budget,
)
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


def test_descriptors_of_one_dtype_and_width_fit_and_an_empty_side_fits_any() -> None:
    """Nothing of an image without keypoints is compared: its descriptors fit whatever their
    width and dtype ((0, 0), or an OpenCV detector's fixed (0, 61) against ORB's 32 bytes)."""
    check_descriptors_fit(_features(5, 8), _features(3, 8), "x")
    check_descriptors_fit(_features(5, 32, np.uint8), _features(0, 32, np.uint8), "x")
    for empty in (_features(0, 0, np.float32), _features(0, 61, np.uint8), _features(0, 0)):
        check_descriptors_fit(_features(5, 32, np.uint8), empty, "x")
        check_descriptors_fit(empty, _features(5, 32, np.uint8), "x")
    with pytest.raises(InvalidInputError):  # with keypoints, the width still counts
        check_descriptors_fit(_features(5, 32, np.uint8), _features(1, 61, np.uint8), "x")


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
    source = CandidateFeatures(Extraction(backend), pre, TileFeatureCache(4), None, False)
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
    off = CandidateFeatures(Extraction(backend), pre, TileFeatureCache(0), None, False)
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


class Scored(Budgeted):
    """A Budgeted whose 8 keypoints have the scores ``SCORES`` (ties included) and descriptors
    that name each keypoint (its index)."""

    def extract(self, image: PreparedImage) -> Features:
        f = super().extract(image)
        named = np.repeat(np.arange(len(f), dtype=np.float32)[:, None], 4, axis=1)
        return Features(f.keypoints, named, SCORES[: len(f)], f.image_size)


SCORES = np.array([0.5, 0.9, 0.1, 0.9, 0.3, 0.5, 0.7, 0.5], np.float32)


@pytest.mark.parametrize(
    ("budget", "kept"),
    [(8, range(8)), (7, [0, 1, 3, 4, 5, 6, 7]), (5, [0, 1, 3, 5, 6]), (2, [1, 3]), (1, [1])],
)
def test_an_extraction_over_the_budget_keeps_its_best_by_score(budget: int, kept: Any) -> None:
    """Descending score, a tie to the earlier keypoint (0.5 at 0, 5 and 7: 0 and 5 kept of
    five), kept in the backend's order, each keypoint with its own descriptor and score."""
    backend = _backend(Scored)
    backend.max_keypoints = budget  # type: ignore[attr-defined]
    whole = backend.extract(_image(64))
    cut = extract_checked(backend, _image(64))
    assert cut.descriptors[:, 0].tolist() == list(kept)
    assert np.array_equal(cut.keypoints, whole.keypoints[list(kept)])
    assert np.array_equal(cut.keypoint_scores, SCORES[list(kept)])
    assert cut.image_size == whole.image_size
    assert cut_to_budget(whole, budget).descriptors[:, 0].tolist() == list(kept)


def test_a_backend_without_a_budget_is_cut_to_the_core_ceiling() -> None:
    backend = _backend(Many)
    assert len(extract_checked(backend, _image(256))) == KEYPOINT_CEILING
    backend.n = KEYPOINT_CEILING + 1  # type: ignore[attr-defined]
    cut = extract_checked(backend, _image(256))
    assert len(cut) == KEYPOINT_CEILING  # all tied: the last one left out
    assert np.array_equal(cut.keypoints, backend.extract(_image(256)).keypoints[:-1])


@pytest.mark.parametrize("declared", [0, -5, True, "8", None, 8.0])
def test_a_declared_budget_that_is_no_positive_int_gives_the_ceiling(declared: Any) -> None:
    backend = _backend(Budgeted)
    backend.max_keypoints = declared  # type: ignore[attr-defined]
    assert extraction_budget(backend)[0] == KEYPOINT_CEILING
    assert backend_budget(backend) is None


@pytest.mark.parametrize("declared", [np.int64(8), np.int32(8), np.uint16(8)])
def test_a_budget_of_any_integer_type_is_read(declared: Any) -> None:
    backend = _backend(Budgeted)
    backend.max_keypoints = declared  # type: ignore[attr-defined]
    assert backend_budget(backend) == extraction_budget(backend)[0] == 8


def test_over_budget_the_query_and_the_tiles_are_cut_and_said_once_per_matcher() -> None:
    """In flight: a query and tiles over the budget are cut to it, not refused: the frames
    find their fix, and one WARNING for the matcher (two frames, the query and every tile
    over) names the backbone, the count and the budget; another matcher says it again."""
    script = [ScriptedCandidate(), ScriptedCandidate(90)]
    frame, calibration = make_frame(uuid.UUID(int=3))
    rerank = make_rerank(frame.frame_id, script)
    stream, fdr = io.StringIO(), InMemoryFdr()
    handle = configure_logging(fdr, level="DEBUG", stream=stream)
    try:
        for _ in range(2):  # two matchers
            backend = Budgeted(FakeInferenceRuntime(script), FakeLightGlueRuntime(script))
            backend.max_keypoints = 5  # type: ignore[attr-defined]
            matcher = scripted_pipeline(backend, FakeRansacFilter(script), fdr, PipelineSettings())
            for _ in range(2):
                assert matcher.match(frame, rerank, calibration).candidates_dropped == 0
    finally:
        handle.close()
    records = [json.loads(line) for line in stream.getvalue().splitlines()]
    cuts = [r for r in records if r["kind"] == KEYPOINTS_CUT]
    assert [(r["level"], r["backbone"], r["keypoints"], r["budget"]) for r in cuts] == [
        ("WARNING", "fake_backend", 8, 5)
    ] * 2
    said = "8 keypoints on a 64x64 px image, more than the 5 backbone fake_backend declares"
    assert said in cuts[0]["message"]
    assert fdr.of_kind("matcher.backbone_error") == []


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


class CountedBudget(FakeBackend):
    """A FakeBackend that declares a budget of 5 and counts how often it is asked for it."""

    asked = 0

    @property
    def max_keypoints(self) -> int:
        self.asked += 1
        return 5


def test_a_matcher_reads_the_budget_once_when_composed_not_every_extraction() -> None:
    """The budget is part of the backend's declared interface, fixed for its life: read when
    the matcher is composed, then two frames (a query and two tiles each, every extraction over
    the budget, so every one is cut) ask for it no more."""
    script = [ScriptedCandidate(), ScriptedCandidate(90)]
    frame, calibration = make_frame(uuid.UUID(int=4))
    backend = CountedBudget(FakeInferenceRuntime(script), FakeLightGlueRuntime(script))
    matcher = scripted_pipeline(
        backend, FakeRansacFilter(script), InMemoryFdr(), PipelineSettings()
    )
    composed = backend.asked
    assert composed >= 1
    for _ in range(2):
        result = matcher.match(frame, make_rerank(frame.frame_id, script), calibration)
        assert result.candidates_dropped == 0
    assert backend.asked == composed
    assert len(Extraction(backend)(_image(64))) == 5  # the cut these frames made


@pytest.mark.parametrize("declared", [None, 0, True, 2048.0])
def test_a_budget_that_is_no_positive_int_composes_and_runs_at_the_ceiling(
    declared: Any, tmp_path: Any, logs: Any
) -> None:
    """One reading of a backend's budget everywhere: a ``max_keypoints`` that is no positive
    integer is no budget, at start-up's inlier check (it was a bare TypeError for None, a
    refusal for 0) as in flight (the core's ceiling, said once at start-up) and for a store's
    precomputed features (none)."""
    from c3_matcher.compose import compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.stages.candidate_features import feature_request
    from c3_matcher.testing import fake_helpers, one_strategy_host, pipeline_strategy

    class Odd(FakeBackend):
        max_keypoints: Any = declared
        extractor_sha256 = "ab" * 32

    host = one_strategy_host("odd", pipeline_strategy(Odd))
    settings = C3Settings(matcher={"strategy": "odd"}, fdr={"path": tmp_path / "fdr.jsonl"})
    helpers = fake_helpers([ScriptedCandidate(100)])
    root = compose_root(settings, helpers, plugin_host=host, configure_logs=False)
    try:
        backend = root.matcher.backend  # type: ignore[attr-defined]
        assert root.matcher._extraction.budget == KEYPOINT_CEILING  # type: ignore[attr-defined]
        assert feature_request(backend, FramePreprocessor(backend.input_rule)) is None
    finally:
        root.close()
    if declared is None:  # declares none: the ceiling, as without max_keypoints, unsaid
        assert logs.of_kind(KEYPOINT_BUDGET_UNREAD) == []
        return
    (said,) = logs.of_kind(KEYPOINT_BUDGET_UNREAD)
    assert said["level"] == "WARNING" and said["declared"] == repr(declared)
    assert f"max_keypoints={declared!r} is no positive integer" in said["message"]


def test_a_matcher_over_a_positive_budget_says_nothing_of_it(logs: Any) -> None:
    Extraction(_backend(Budgeted))
    Extraction(_backend(FakeBackend))  # none declared: the ceiling, as documented
    assert logs.of_kind(KEYPOINT_BUDGET_UNREAD) == []
