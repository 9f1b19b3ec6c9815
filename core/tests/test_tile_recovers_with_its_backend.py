"""A tile whose features a frame refuses, or could not match, leaves the tile cache: once the
backend answers well again, so does the tile, the next frame extracting it anew rather than
failing on what was cached. A tile extracted with descriptors that do not fit the query's is
dropped in the backend's extract phase naming both, not in the matcher's library; a match that
returns something other than ``RawMatches`` is named so. A real ORB backend, wrong for one call,
on the demo frame and its real tiles, real RANSAC, the tile cache on."""

from __future__ import annotations

import dataclasses
import io
import json
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher.demo import demo_inputs
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.features import Features
from c3_matcher.health import RollingHealthWindow
from c3_matcher.logs import configure_logging
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.probe import engine_startup_probe
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.stages.extract import KEYPOINTS_CUT
from c3_matcher.testing import FakeClock, InMemoryFdr

from .test_contract_kit import OpenCvBackend

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
TRUE = 1  # the demo frame's true tile: the second candidate
TRUE_EXTRACT, TRUE_MATCH = 3, 2  # its calls in the first frame (the query is extract's first)


class OnceWrong:
    """ORB + cross-checked brute force, wrong for one call: extract's call ``extract_at``
    returns ``extracted`` of its features, match's call ``match_at`` returns ``matched`` (or
    raises it, an exception)."""

    label, extract_phase, match_phase = "orb", "orb_detect", "bf_hamming"

    def __init__(
        self,
        extract_at: int = 0,
        extracted: Any = None,
        match_at: int = 0,
        matched: Any = None,
    ) -> None:
        self._inner = OpenCvBackend(cv2.ORB_create(2000), cv2.NORM_HAMMING, "orb")
        self.input_rule = self._inner.input_rule
        self.extract_at, self.extracted, self.match_at, self.matched = (
            extract_at,
            extracted,
            match_at,
            matched,
        )
        self.extracts = self.matches = 0

    def extract(self, image: PreparedImage) -> Any:
        self.extracts += 1
        features = self._inner.extract(image)
        return self.extracted(features) if self.extracts == self.extract_at else features

    def match(self, query: Features, tile: Features) -> Any:
        self.matches += 1
        if self.matches != self.match_at:
            return self._inner.match(query, tile)
        if isinstance(self.matched, Exception):
            raise self.matched
        return self.matched

    def provenance(self) -> dict[str, Any]:
        return self._inner.provenance()


def _matcher(backend: OnceWrong, fdr: InMemoryFdr) -> PipelineMatcher:
    clock = FakeClock()
    settings = PipelineSettings(tile_cache_size=3)
    health = RollingHealthWindow(clock, settings.min_inliers_threshold)
    return PipelineMatcher(backend, OpenCvRansacFilter(), fdr, health, clock, settings)


def _narrow(features: Features) -> Features:
    """The same keypoints with half of each ORB descriptor (16 bytes of its 32)."""
    return dataclasses.replace(
        features, descriptors=np.ascontiguousarray(features.descriptors[:, :16])
    )


def _true_tile_reason(fdr: InMemoryFdr) -> str:
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    (dropped,) = [d for d in record["dropped"] if d["candidate_index"] == TRUE]
    return str(dropped["reason"])


def test_the_tiles_stay_cached_while_the_backend_answers_well() -> None:
    """The control: two frames, the second matching every tile from the cache."""
    frame, rerank, calibration = demo_inputs(DEMO)
    matcher = _matcher(OnceWrong(), InMemoryFdr())
    first = matcher.match(frame, rerank, calibration)
    again = matcher.match(frame, rerank, calibration)
    assert first.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert again.per_candidate[0].inlier_count == first.per_candidate[0].inlier_count
    assert again.diagnostics["candidate_features"] == ["cached"] * 3


@pytest.mark.parametrize(
    ("narrowed", "said"),
    [
        (_narrow, ", 16) uint8 do not fit"),
        (
            lambda f: dataclasses.replace(f, descriptors=f.descriptors.astype(np.float32)),
            ", 32) float32 do not fit",
        ),
    ],
    ids=["16 bytes wide", "float32"],
)
def test_a_tile_whose_descriptors_do_not_fit_is_dropped_in_extract_and_recovers(
    narrowed: Any, said: str
) -> None:
    """The true tile extracted once with descriptors unlike the query's (16 bytes for 32, or
    float32 for packed bits): dropped in the extract phase naming both arrays and the backbone,
    not in the matcher; the next frame extracts it anew and finds the fix on it."""
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    matcher = _matcher(OnceWrong(extract_at=TRUE_EXTRACT, extracted=narrowed), fdr)
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)
    reason = _true_tile_reason(fdr)
    start = "backbone error in orb_detect: InvalidInputError: features.descriptors: the tile's "
    assert reason.startswith(start) and said in reason
    assert re.search(r"the query's \(\d+, 32\) uint8 \(backbone orb\)", reason), reason
    again = matcher.match(frame, rerank, calibration)
    assert again.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert again.per_candidate[0].inlier_count >= 60
    assert again.diagnostics["candidate_features"] == ["cached", "extracted", "cached"]


@pytest.mark.parametrize("answer", [None, np.zeros((3, 2), np.int64), ((0, 0),)])
def test_a_match_that_returns_no_raw_matches_is_named_and_its_tile_recovers(answer: Any) -> None:
    """The true tile's match returns None, a bare array or a tuple once: dropped in the match
    phase naming what it returned and the backbone; the tile, cached as it was extracted, leaves
    the cache, and the next frame extracts and matches it again."""
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    matcher = _matcher(OnceWrong(match_at=TRUE_MATCH, matched=answer), fdr)
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)
    kind = type(answer).__name__
    said = f"backbone error in bf_hamming: InvalidInputError: raw_matches: match returned {kind}"
    assert _true_tile_reason(fdr).startswith(f"{said}, not RawMatches (backbone orb)")
    again = matcher.match(frame, rerank, calibration)
    assert again.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert again.diagnostics["candidate_features"] == ["cached", "extracted", "cached"]


def test_a_raising_match_sends_its_tile_out_of_the_cache_too() -> None:
    """A match that raises once on the true tile: its tile is extracted anew next frame."""
    frame, rerank, calibration = demo_inputs(DEMO)
    fdr = InMemoryFdr()
    matcher = _matcher(OnceWrong(match_at=TRUE_MATCH, matched=RuntimeError("matcher down")), fdr)
    with pytest.raises(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)
    assert _true_tile_reason(fdr) == "backbone error in bf_hamming: RuntimeError: matcher down"
    again = matcher.match(frame, rerank, calibration)
    assert again.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert again.diagnostics["candidate_features"] == ["cached", "extracted", "cached"]


def _logged(run: Any) -> tuple[list[dict[str, Any]], InMemoryFdr]:
    """The JSON log records (DEBUG and up) of ``run(fdr)``, and the FDR it was given."""
    stream, fdr = io.StringIO(), InMemoryFdr()
    handle = configure_logging(fdr, level="DEBUG", stream=stream)
    try:
        run(fdr)
    finally:
        handle.close()
    return [json.loads(line) for line in stream.getvalue().splitlines()], fdr


class Sift500(OpenCvBackend):
    """OpenCV SIFT asked for 500 keypoints, declaring 500 its budget, as the plugin guide has it:
    on the demo's true tile SIFT keeps the keypoint tied with the 500th and gives 501."""

    max_keypoints = 500

    def __init__(self) -> None:
        super().__init__(cv2.SIFT_create(500), cv2.NORM_L2, "sift")


def test_a_backend_one_keypoint_over_its_budget_keeps_its_fix_said_once() -> None:
    """The true tile's 501 SIFT keypoints are cut to the 500 of highest score, not refused: the
    frame finds its fix there, as the start-up probe passed; one WARNING names the backbone,
    the count and the budget, and the next frame (the tiles cached) says nothing more."""
    frame, rerank, calibration = demo_inputs(DEMO)
    backend = Sift500()
    engine_startup_probe(backend)
    results = []

    def run(fdr: InMemoryFdr) -> None:
        matcher = _matcher(backend, fdr)  # type: ignore[arg-type]
        results.extend(matcher.match(frame, rerank, calibration) for _ in range(2))

    records, fdr = _logged(run)
    for result in results:
        assert result.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
        assert result.per_candidate[0].inlier_count >= 60
    (cut,) = [r for r in records if r["kind"] == KEYPOINTS_CUT]
    assert (cut["level"], cut["backbone"], cut["budget"]) == ("WARNING", "sift", 500)
    assert cut["keypoints"] > 500
    assert fdr.of_kind("matcher.backbone_error") == []


@pytest.mark.parametrize("width", [0, 61], ids=["(0, 0)", "(0, 61)"])
def test_a_blank_tile_whose_empty_descriptors_have_another_width_is_no_error(width: int) -> None:
    """The first candidate's tile blank (water, haze): ORB finds no keypoint there and the
    backend answers descriptors (0, 0) or (0, 61) against the query's (K, 32). Nothing is
    compared: a DEBUG zero-inlier drop, no backbone error, and the tile stays cached (the next
    frame serves it from the cache)."""
    frame, rerank, calibration = demo_inputs(DEMO)

    def blank(features: Features) -> Features:
        empty = np.zeros((0, 2), np.float32)
        none = np.zeros((0, width), np.uint8)
        return Features(empty, none, np.zeros(0, np.float32), features.image_size)

    results = []

    def run(fdr: InMemoryFdr) -> None:
        matcher = _matcher(OnceWrong(extract_at=2, extracted=blank), fdr)
        results.extend(matcher.match(frame, rerank, calibration) for _ in range(2))

    records, fdr = _logged(run)
    assert fdr.of_kind("matcher.backbone_error") == []
    zero = [r for r in records if r["kind"] == "c3.matcher.zero_inliers"]
    assert [r["level"] for r in zero if r["candidate_index"] == 0] == ["DEBUG", "DEBUG"]
    for result in results:
        assert result.per_candidate[0].tile_id == rerank.candidates[TRUE].tile_id
    assert results[1].diagnostics["candidate_features"] == ["cached"] * 3
