"""The frame recorder (one health update, backbone errors counted, FDR failures logged, the
terminal records), the ranking and the values that travel between the stages."""

from __future__ import annotations

from typing import Any

import numpy as np

from c3_matcher.dto import CandidateMatchSet, TileId
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.health import RollingHealthWindow
from c3_matcher.prepared import PreparedImage
from c3_matcher.stages.outcomes import (
    Dropped,
    FrameEvidence,
    GeometryRefusal,
    RefineRecord,
    Survivor,
    TileFeatures,
)
from c3_matcher.stages.ranking import best_inlier_count, ranked, top
from c3_matcher.stages.recorder import FrameRecorder, RecorderSinks
from c3_matcher.testing import FakeBackend, FakeClock, FakeInferenceRuntime, FakeLightGlueRuntime


def _sinks(fdr: Any = None) -> tuple[RecorderSinks, RollingHealthWindow]:
    clock = FakeClock()
    health = RollingHealthWindow(clock, 60)
    backend = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    return RecorderSinks(fdr or InMemoryFdr(), health, clock, backend), health


def _survivor(index: int, inliers: int, residual: float) -> Survivor:
    rows = np.zeros((inliers, 4), np.float32)
    match_set = CandidateMatchSet(TileId(18, 47.0 + index / 1000, 8.5), inliers, rows, 3, residual)
    image = PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (16, 16)
    )
    tile = TileFeatures("extracted", image, None)  # type: ignore[arg-type]
    return Survivor(match_set, index, np.eye(3), 0, tile)


def test_health_is_updated_once_and_reports_recorded_backbone_errors():
    sinks, health = _sinks()
    recorder = FrameRecorder(sinks, "f")
    recorder.backbone_error("tile", "disk_forward", RuntimeError("boom"), candidate_index=1)
    recorder.update_health(120)
    recorder.update_health(0, force_backbone_error=True)  # the first update wins
    assert health.update_count == 1
    last = health.last_update
    assert last is not None and last.best_inlier_count == 120 and last.had_backbone_error


def test_the_backbone_error_record_names_tile_phase_and_error():
    fdr = InMemoryFdr()
    FrameRecorder(_sinks(fdr)[0], "f").backbone_error("tile", "ransac", ValueError("x"), 2)
    assert fdr.of_kind("matcher.backbone_error") == [
        {
            "frame_id": "f",
            "tile_id": "tile",
            "candidate_index": 2,
            "phase": "ransac",
            "error": "ValueError: x",
            "backbone": "fake_backend",
        }
    ]


def test_a_failing_fdr_never_fails_the_frame():
    class Down:
        def record(self, kind: str, payload: Any) -> None:
            raise OSError("disk full")

    FrameRecorder(_sinks(Down())[0], "f").record("matcher.frame_done", {})  # no exception


def _refused_evidence() -> FrameEvidence:
    """Three candidates: 0 refused on geometry (40 inliers), 1 kept, 2 dropped unmatched."""
    refusal = GeometryRefusal(TileId(18, 47.0, 8.5), 0, 40, "scale 1.5", None)
    return FrameEvidence(
        3, ("stored", "extracted", "none"), ({}, {}, {}), 2, (refusal,), False, None
    )


def _assert_candidates_recorded(record: dict[str, Any]) -> None:
    assert record["candidate_features"] == ["stored", "extracted", "none"]
    assert record["per_candidate"][0]["features"] == "extracted"
    assert [(r["reason"], r["inlier_count"]) for r in record["geometry_refused"]] == [
        ("scale 1.5", 40)
    ]


def test_insufficient_records_the_evidence_and_returns_the_error():
    fdr = InMemoryFdr()
    sinks, health = _sinks(fdr)
    recorder = FrameRecorder(sinks, "f")
    error = recorder.insufficient(_refused_evidence(), 20, [_survivor(1, 20, 1.0)], 60)
    assert (error.best_inlier_count, error.threshold, error.candidates_dropped) == (20, 60, 2)
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    _assert_candidates_recorded(record)
    assert "stale_rerank" not in record and "refine" not in record
    assert health.update_count == 1 and health.last_update.best_inlier_count == 0  # type: ignore[union-attr]


def test_a_frame_whose_matches_were_refused_on_geometry_says_their_inliers():
    """ "best inlier count 0" read as "nothing matched" when the prior refused a candidate of
    hundreds of inliers (a heading error past its tolerance): the error and the ERROR log name
    the refused, the most inliers first."""
    from loguru import logger

    wide = GeometryRefusal(TileId(18, 47.0, 8.5), 2, 532, "rotation -15.1 deg beyond 10.0 deg")
    few = GeometryRefusal(TileId(18, 47.1, 8.5), 0, 12, "scale 1.5")
    evidence = FrameEvidence(3, ("extracted",) * 3, ({}, {}, {}), 3, (few, wide), False, None)
    said: list[str] = []
    sink = logger.add(lambda m: said.append(m.record["message"]), level="ERROR")
    try:
        error = FrameRecorder(_sinks()[0], "f").insufficient(evidence, 0, [], 60)
    finally:
        logger.remove(sink)
    assert error.geometry_refused == ((532, wide.reason), (12, "scale 1.5"))
    words = "2 of them refused on geometry whatever their inliers, the most 532 inliers: rotation"
    assert words in str(error), error
    assert any(words in line for line in said), said


def test_the_success_record_names_the_candidates_refused_on_geometry_too():
    """A frame that finds its fix still says which candidate the prior refused and why: in
    flight that is the FDR's only account of it (the refusal's log line is DEBUG)."""
    fdr = InMemoryFdr()
    recorder = FrameRecorder(_sinks(fdr)[0], "f")
    recorder.frame_done(_refused_evidence(), [_survivor(1, 90, 1.0)], None, {"total": 5.0}, 60)
    (record,) = fdr.of_kind("matcher.frame_done")
    _assert_candidates_recorded(record)
    assert record["best_inlier_count"] == 90 and record["timings_ms"] == {"total": 5.0}
    assert record["threshold"] == 60  # the one it passed, as the no-fix record names its own


def test_a_stale_rerank_is_named_in_the_record():
    fdr = InMemoryFdr()
    recorder = FrameRecorder(_sinks(fdr)[0], "now")
    recorder.insufficient(FrameEvidence(2, dropped=2), 0, [], 60, stale_rerank_frame_id="then")
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["stale_rerank"] == "then" and record["candidates_dropped"] == 2


def test_ranking_is_by_inliers_then_residual_stable_on_ties():
    a, b, c, d = (
        _survivor(0, 80, 1.0),
        _survivor(1, 120, 1.4),
        _survivor(2, 120, 1.1),
        _survivor(3, 120, 1.1),
    )
    assert [s.input_index for s in ranked([a, b, c, d])] == [2, 3, 1, 0]
    assert top([a, b, c, d]) is c
    assert best_inlier_count([a, b]) == 120 and best_inlier_count([]) == 0


def test_evidence_of_the_candidates_in_input_order():
    refusal = GeometryRefusal(TileId(18, 47.0, 8.5), 2, 40, "rotation", 90)
    candidates = [_survivor(0, 80, 1.0), Dropped(1, "none"), Dropped(2, "cached", refusal=refusal)]
    evidence = FrameEvidence.of(candidates, rotation_search=True, refine=None)
    assert evidence.sources == ("extracted", "none", "cached")
    assert (evidence.candidates_input, evidence.dropped, evidence.refused) == (3, 2, (refusal,))
    assert refusal.as_record()["rotation_deg"] == 90
    assert "rotation_deg" not in GeometryRefusal(TileId(18, 47.0, 8.5), 2, 40, "r").as_record()


def test_the_refine_record_says_why_only_when_not_kept():
    kept = RefineRecord(1, 80, 95, kept=True).as_record()
    assert kept == {"candidate_index": 1, "inliers_before": 80, "inliers_after": 95, "kept": True}
    refused = RefineRecord(1, 80, reason="ranks no better than the first pass").as_record()
    assert list(refused) == ["candidate_index", "inliers_before", "inliers_after", "kept", "reason"]


def test_the_match_commands_drop_reasons_are_read_from_the_recorders_log_events():
    """``c3-matcher match`` says why each dropped candidate went by listening to the log kinds
    the recorder writes; a kind renamed on one side only would silently lose every reason."""
    from c3_matcher.stages.drops import drops_heard

    with drops_heard() as heard:
        recorder = FrameRecorder(_sinks()[0], "f")
        recorder.backbone_error("18,1,2", "lightglue_match", RuntimeError("boom"), 0)
        recorder.zero_inliers("18,3,4", 1, raw_matches=7)
        recorder.zero_inliers("18,3,4", 2, raw_matches=9)  # the same tile id twice: by position
        recorder.geometry_refused(GeometryRefusal("18,5,6", 3, 41, "rotation 45.0 deg"))
        recorder.backbone_error(None, "query_extract", RuntimeError("no"))  # no candidate's
    reasons = {i: drop.reason for i, drop in heard.items()}
    assert heard[0].event["phase"] == "lightglue_match"  # what a run counts it under
    assert reasons == {
        0: "backbone error in lightglue_match: RuntimeError: boom",
        1: "no inliers after RANSAC (7 raw matches)",
        2: "no inliers after RANSAC (9 raw matches)",
        3: "refused on geometry: rotation 45.0 deg (41 inliers)",
    }
