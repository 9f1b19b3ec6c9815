"""The shared per-frame pipeline: the matcher contract's criteria 2-10 and 12 with the allowed test
doubles."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from c3_matcher.dto import Attitude
from c3_matcher.errors import InsufficientInliersError, MatcherBackboneError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.testing import (
    FakeBackend,
    ScriptedCandidate,
    ScriptedRig,
)

S = ScriptedCandidate


def test_ac2_best_candidate_argmax_with_residual_tie_break(fdr, logs):
    rig = ScriptedRig([S(120, 1.4), S(80, 1.0), S(120, 1.1)], fdr)
    result = rig.match()
    assert result.best_candidate_idx == 0
    got = [(c.inlier_count, c.per_candidate_residual_px) for c in result.per_candidate]
    assert got == [(120, 1.1), (120, 1.4), (80, 1.0)]
    assert [c.tile_id for c in result.per_candidate] == [
        rig.rerank.candidates[i].tile_id for i in (2, 0, 1)
    ]
    assert result.reprojection_residual_px == 1.1


def test_inv3_full_tie_keeps_input_order(fdr, logs):
    rig = ScriptedRig([S(90, 1.0), S(90, 1.0), S(90, 1.0)], fdr)
    result = rig.match()
    assert [c.tile_id for c in result.per_candidate] == [c.tile_id for c in rig.rerank.candidates]


def test_ac3_extractor_failure_on_second_candidate_is_dropped(fdr, logs):
    rig = ScriptedRig([S(100), S(100, fail_extract=True), S(90)], fdr)
    result = rig.match()
    assert len(result.per_candidate) == 2
    assert result.candidates_dropped == 1 and result.candidates_input == 3
    errors = logs.of_kind("c3.matcher.backbone_error")
    assert len(errors) == 1 and errors[0]["level"] == "ERROR"
    assert errors[0]["phase"] == "disk_forward"
    assert errors[0]["tile_id"] == rig.rerank.candidates[1].tile_id.as_list()
    records = fdr.of_kind("matcher.backbone_error")
    assert len(records) == 1 and records[0]["phase"] == "disk_forward"
    assert rig.health.last_update is not None and rig.health.last_update.had_backbone_error


def test_ac4_lightglue_failure_on_first_candidate_is_dropped(fdr, logs):
    rig = ScriptedRig([S(100, fail_match=True), S(100), S(90)], fdr)
    result = rig.match()
    assert [c.tile_id for c in result.per_candidate] == [
        rig.rerank.candidates[1].tile_id,
        rig.rerank.candidates[2].tile_id,
    ]
    assert [e["phase"] for e in logs.of_kind("c3.matcher.backbone_error")] == ["lightglue_match"]
    assert [r["phase"] for r in fdr.of_kind("matcher.backbone_error")] == ["lightglue_match"]
    assert rig.lightglue.calls == [0, 1, 2]  # the remaining candidates were processed


def test_tile_decode_failure_is_a_backbone_drop(fdr, logs):
    rig = ScriptedRig([S(100), S(100), S(100, fail_decode=True)], fdr)
    result = rig.match()
    assert result.candidates_dropped == 1
    assert fdr.of_kind("matcher.backbone_error")[0]["phase"] == "tile_decode"


class _UnprintableError(Exception):
    def __str__(self) -> str:
        raise ValueError("this message cannot be read")


class _HandleRaisingUnprintable:
    """A third party's tile handle whose error cannot even say what it is."""

    def encoded(self) -> memoryview:
        return memoryview(b"x")

    def decode(self):
        raise _UnprintableError


def test_a_candidate_error_whose_message_fails_drops_that_candidate_only(fdr, logs):
    rig = ScriptedRig([S(100), S(100), S(90)], fdr)
    second = rig.rerank.candidates[1]
    odd = dataclasses.replace(second, tile_pixels_handle=_HandleRaisingUnprintable())
    rig.rerank = dataclasses.replace(
        rig.rerank, candidates=(rig.rerank.candidates[0], odd, rig.rerank.candidates[2])
    )
    result = rig.match()
    assert result.candidates_dropped == 1 and len(result.per_candidate) == 2
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert record["phase"] == "tile_decode"
    assert record["error"] == "_UnprintableError: <its message could not be read: ValueError>"


def test_ac5_all_below_threshold_raises_insufficient(fdr, logs):
    rig = ScriptedRig([S(59), S(10), S(30)], fdr)
    with pytest.raises(InsufficientInliersError) as info:
        rig.match()
    assert info.value.best_inlier_count == 59 and info.value.threshold == 60
    assert len(logs.of_kind("c3.matcher.insufficient_inliers")) == 1
    assert logs.of_kind("c3.matcher.insufficient_inliers")[0]["level"] == "ERROR"
    assert len(fdr.of_kind("matcher.insufficient_inliers")) == 1
    assert rig.health.update_count == 1
    last = rig.health.last_update
    assert last is not None and last.best_inlier_count == 0 and last.had_backbone_error is False
    assert fdr.of_kind("matcher.frame_done") == []


def test_a_best_with_exactly_the_threshold_of_inliers_gets_its_fix(fdr, logs):
    """``min_inliers_threshold`` is the least a fix needs: 60 inliers pass it (59 do not:
    the test above)."""
    rig = ScriptedRig([S(60), S(10), S(30)], fdr)
    assert rig.settings.min_inliers_threshold == 60
    result = rig.match()
    assert [c.inlier_count for c in result.per_candidate] == [60, 30, 10]
    (record,) = fdr.of_kind("matcher.frame_done")
    assert record["best_inlier_count"] == 60 and record["threshold"] == 60
    assert fdr.of_kind("matcher.insufficient_inliers") == []


def test_no_candidate_at_all_is_no_fix_not_a_refused_input(fdr, logs):
    """A re-ranker with no tile to propose (none near the estimate) hands over an empty
    re-rank: the frame ends as any frame without a fix does, which is the VIO fallback's cue."""
    rig = ScriptedRig([], fdr)
    assert rig.rerank.candidates == ()
    with pytest.raises(InsufficientInliersError) as info:
        rig.match()
    assert (info.value.candidates_input, info.value.candidates_dropped) == (0, 0)
    assert [kind for kind, _ in fdr.records] == ["log.error", "matcher.insufficient_inliers"]
    assert fdr.of_kind("matcher.insufficient_inliers")[0]["candidates_input"] == 0
    assert rig.health.update_count == 1
    last = rig.health.last_update
    assert last is not None and last.best_inlier_count == 0 and last.had_backbone_error is False
    assert rig.inference.calls == []  # nothing to match: the nav frame is not even extracted


def test_ac6_all_extractors_fail(fdr, logs):
    rig = ScriptedRig([S(fail_extract=True)] * 3, fdr)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    assert len(logs.of_kind("c3.matcher.backbone_error")) == 3
    assert len(logs.of_kind("c3.matcher.insufficient_inliers")) == 1
    assert len(fdr.of_kind("matcher.backbone_error")) == 3
    last = rig.health.last_update
    assert rig.health.update_count == 1
    assert last is not None and last.best_inlier_count == 0 and last.had_backbone_error is True


def test_zero_inliers_is_dropped_without_backbone_error(fdr, logs):
    rig = ScriptedRig([S(100), S(0), S(70)], fdr)
    result = rig.match()
    assert result.candidates_dropped == 1 and len(result.per_candidate) == 2
    assert len(logs.of_kind("c3.matcher.zero_inliers")) == 1
    assert logs.of_kind("c3.matcher.backbone_error") == []
    last = rig.health.last_update
    assert last is not None and last.had_backbone_error is False and last.best_inlier_count == 100


def test_ac7_warn_when_best_residual_above_threshold(fdr, logs):
    rig = ScriptedRig([S(100, 4.2), S(80, 1.0), S(70, 1.0)], fdr)
    rig.match()
    warns = logs.of_kind("c3.matcher.residual_above_threshold")
    assert len(warns) == 1 and warns[0]["level"] == "WARNING"
    assert warns[0]["residual_px"] == 4.2 and warns[0]["threshold_px"] == 2.5
    # WARN is forwarded to the FDR as its own kind
    assert len(fdr.of_kind("log.warning")) == 1


def test_no_warn_at_or_below_threshold(fdr, logs):
    rig = ScriptedRig([S(100, 2.5)], fdr)
    rig.match()
    assert logs.of_kind("c3.matcher.residual_above_threshold") == []


@pytest.mark.parametrize(
    "script",
    [
        [S(100), S(90), S(80)],
        [S(100), S(90, fail_extract=True), S(80)],
        [S(10), S(20), S(30)],
        [S(fail_match=True)] * 3,
    ],
)
def test_ac8_health_updated_exactly_once_per_call(fdr, logs, script):
    rig = ScriptedRig(script, fdr)
    for expected in (1, 2):
        try:
            result = rig.match()
            best = result.per_candidate[0].inlier_count
        except InsufficientInliersError:
            best = 0
        assert rig.health.update_count == expected
        last = rig.health.last_update
        assert last is not None and last.best_inlier_count == best
        assert last.had_backbone_error == any(s.fail_extract or s.fail_match for s in script)


def test_ac9_correspondence_shape(fdr, logs):
    result = ScriptedRig([S(120), S(75), S(64)], fdr).match()
    for c in result.per_candidate:
        assert c.inlier_correspondences.shape == (c.inlier_count, 4)
        assert c.inlier_correspondences.dtype.name == "float32"


def test_ac10_deterministic_three_calls(fdr, logs):
    rig = ScriptedRig([S(120, 1.4), S(80, 1.0), S(120, 1.1)], fdr)
    results = [rig.match() for _ in range(3)]
    for other in results[1:]:
        assert other.best_candidate_idx == results[0].best_candidate_idx
        assert other.reprojection_residual_px == results[0].reprojection_residual_px
        assert all(
            a.same_content(b)
            for a, b in zip(results[0].per_candidate, other.per_candidate, strict=True)
        )


def test_ac12_frame_done_record(fdr, logs):
    rig = ScriptedRig([S(120, 1.1), S(fail_extract=True), S(80, 1.5)], fdr)
    result = rig.match()
    done = fdr.of_kind("matcher.frame_done")
    assert len(done) == 1
    record = done[0]
    assert record["frame_id"] == str(rig.frame.frame_id)
    assert record["candidates_input"] == 3 and record["candidates_dropped"] == 1
    assert record["best_inlier_count"] == 120 and record["best_residual_px"] == 1.1
    assert record["best_tile_id"] == result.per_candidate[0].tile_id.as_list()
    assert record["provider"] == "FakeExecutionProvider"
    assert "timings_ms" in record and record["best_homography"] is not None
    per = record["per_candidate_timings_ms"]  # every candidate's stages, in input order
    assert [sorted(t) for t in per] == [
        sorted(t) for t in result.diagnostics["per_candidate_timings_ms"]
    ]
    assert {"extract", "match", "ransac"} <= set(per[0]) and "match" not in per[1]


@pytest.mark.parametrize("attitude", [None, Attitude(0.08, -0.05, 0.6)])
def test_the_frame_done_record_says_which_pixels_its_homography_maps(fdr, logs, attitude):
    """The record's ``best_homography`` maps the px the query was matched in (rectified with
    an attitude); ``query_rectification`` takes UNDISTORTED px there, so the two compose to the
    result's ``query_to_tile``, the map its JSON reports."""
    result = ScriptedRig([S(120, 1.1), S(80, 1.5)], fdr, attitude=attitude).match()
    (record,) = fdr.of_kind("matcher.frame_done")
    hom = np.asarray(record["best_homography"], dtype=np.float64)
    best, other = result.diagnostics["homographies"]
    assert not np.allclose(best, other), "the doubles give each candidate its own homography"
    assert np.array_equal(hom, best)
    rect = np.asarray(record["query_rectification"], dtype=np.float64)
    assert rect.shape == (3, 3) and np.allclose(rect, np.eye(3)) == (attitude is None)
    composed = hom @ rect
    np.testing.assert_allclose(composed / composed[2, 2], result.diagnostics["query_to_tile"][0])


def test_an_insufficient_record_says_where_each_candidates_time_went(fdr, logs):
    rig = ScriptedRig([S(59), S(10)], fdr)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    per = record["per_candidate_timings_ms"]
    assert len(per) == 2 and all({"extract", "match", "ransac"} <= set(t) for t in per)
    assert all(v >= 0 for t in per for v in t.values())


def test_query_failure_raises_backbone_error_and_updates_health(fdr, logs):
    rig = ScriptedRig([S(100)], fdr)
    rig.inference.script = [S()] * 255  # mark 255 (the query) -> index 254 fails
    rig.inference.script[254] = S(fail_extract=True)
    with pytest.raises(MatcherBackboneError) as info:
        rig.match()
    assert info.value.phase == "query_extract"
    assert [r["phase"] for r in fdr.of_kind("matcher.backbone_error")] == ["query_extract"]
    last = rig.health.last_update
    assert rig.health.update_count == 1 and last is not None and last.had_backbone_error


def test_fdr_failure_never_fails_the_frame(logs):
    class BrokenFdr(InMemoryFdr):
        def record(self, kind, payload):  # type: ignore[no-untyped-def]
            raise OSError("disk full")

    rig = ScriptedRig([S(100)], BrokenFdr())
    assert rig.match().per_candidate[0].inlier_count == 100
    assert len(logs.of_kind("c3.fdr.write_failed")) == 1


def test_tile_cache_reuses_features_and_gives_identical_results(fdr, logs):

    rig = ScriptedRig([S(120, 1.4), S(80, 1.0), S(120, 1.1)], fdr)
    rig.pipeline = PipelineMatcher(
        FakeBackend(rig.inference, rig.lightglue),
        rig.ransac,
        fdr,
        rig.health,
        rig.clock,
        dataclasses.replace(rig.settings, tile_cache_size=3),
    )
    first = rig.match()
    calls_after_first = len(rig.inference.calls)
    second = rig.match()
    assert len(rig.inference.calls) - calls_after_first == 1  # only the query is extracted
    assert second.diagnostics["tile_cache"] == {"hits": 3, "misses": 3}
    assert all(
        a.same_content(b) for a, b in zip(first.per_candidate, second.per_candidate, strict=True)
    )


def test_tile_cache_key_changes_with_the_bytes():
    from c3_matcher.dto import TileId
    from c3_matcher.tile_cache import tile_cache_key
    from c3_matcher.tiles import BytesTileHandle

    tile = TileId(18, 47.0, 8.0)
    assert tile_cache_key(tile, BytesTileHandle(b"abc")) == tile_cache_key(
        tile, BytesTileHandle(b"abc")
    )
    assert tile_cache_key(tile, BytesTileHandle(b"abc")) != tile_cache_key(
        tile, BytesTileHandle(b"abd")
    )


def test_matcher_settings_reach_the_pipeline_of_every_strategy(tmp_path):
    """[matcher] stored_features and the geometric prior travel by injection (config ->
    strategy config -> PipelineSettings), never through process-wide state."""
    from pathlib import Path

    from c3_matcher.config import load_settings
    from c3_matcher.strategy import ExtractorLightGlueConfig

    toml = tmp_path / "c3.toml"
    toml.write_text(
        "[matcher]\nstored_features = false\ngeometric_prior = false\n"
        "prior_rotation_tol_deg = 5.0\nmin_inliers_threshold = 70\n"
    )
    settings = load_settings(toml, env={})
    config = ExtractorLightGlueConfig.from_settings(
        settings,
        label="x",
        feature_type="disk",
        extract_phase="disk_forward",
        extractor_engine_path=Path("e.onnx"),
        lightglue_engine_path=Path("l.onnx"),
        size_multiple=16,
    )
    pipeline = config.pipeline
    assert not pipeline.stored_features and not pipeline.geometric_prior  # both not default
    assert pipeline.prior_tolerances.rotation_deg == 5.0
    assert pipeline.min_inliers_threshold == 70
    assert load_settings(env={}) and PipelineSettings().geometric_prior  # defaults untouched
