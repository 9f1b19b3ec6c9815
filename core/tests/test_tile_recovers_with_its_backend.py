"""A tile whose features a frame refuses, or could not match, leaves the tile cache: once the
backend answers well again, so does the tile, the next frame extracting it anew rather than
failing on what was cached. A tile extracted with descriptors that do not fit the query's is
dropped in the backend's extract phase naming both, not in the matcher's library; a match that
returns something other than ``RawMatches`` is named so. A real ORB backend, wrong for one call,
on the demo frame and its real tiles, real RANSAC, the tile cache on."""

from __future__ import annotations

import dataclasses
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
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.prepared import PreparedImage
from c3_matcher.ransac import OpenCvRansacFilter
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
