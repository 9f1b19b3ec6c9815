"""What can happen in flight reaches the caller as one of the contract's two errors, with its
FDR record and exactly one health update: a re-rank made for another frame (stale) is
``InsufficientInliersError`` with every candidate dropped unmatched; no frame at all
(``frame=None``) is a query failure, ``MatcherBackboneError`` in phase ``query_extract``. Only a
caller's programming error (an argument of the wrong type) raises ``InvalidInputError``.
Scripted doubles for the control flow, then the real engines on the demo frame."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.demo import demo_inputs
from c3_matcher.dto import RerankResult
from c3_matcher.errors import (
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
    MatcherClosedError,
)
from c3_matcher.fdr import InMemoryFdr, read_fdr
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.testing import ScriptedCandidate, ScriptedRig, make_rerank

S = ScriptedCandidate
DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"


def test_stale_rerank_is_insufficient_inliers_with_its_record(fdr, logs):
    rig = ScriptedRig([S(100), S(90)], fdr)
    stale = make_rerank(uuid.UUID(int=8), rig.script)
    with pytest.raises(InsufficientInliersError) as info:
        rig.pipeline.match(rig.frame, stale, rig.calibration)
    err = info.value
    assert err.frame_id == rig.frame.frame_id and err.best_inlier_count == 0
    assert (err.candidates_input, err.candidates_dropped) == (2, 2)
    assert rig.inference.calls == []  # nothing of another frame was matched
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["frame_id"] == str(rig.frame.frame_id)
    assert record["stale_rerank"] == str(uuid.UUID(int=8))
    assert record["candidates_dropped"] == 2 and record["per_candidate"] == []
    why = f"the re-rank was made for frame {uuid.UUID(int=8)}"  # each of them named, with why
    tiles = [c.tile_id.as_list() for c in stale.candidates]
    assert record["dropped"] == [
        {"candidate_index": i, "tile_id": tile, "reason": why} for i, tile in enumerate(tiles)
    ]
    assert fdr.of_kind("matcher.invalid_input") == []
    last = rig.health.last_update
    assert rig.health.update_count == 1 and last is not None
    assert last.best_inlier_count == 0 and not last.had_backbone_error
    (line,) = logs.of_kind("c3.matcher.insufficient_inliers")
    assert "re-rank is for frame" in line["message"]
    assert rig.match().per_candidate[0].inlier_count == 100  # the next good frame matches


def test_missing_frame_is_a_query_backbone_error_with_its_record(fdr, logs):
    rig = ScriptedRig([S(100)], fdr)
    with pytest.raises(MatcherBackboneError) as info:
        rig.pipeline.match(None, rig.rerank, rig.calibration)  # type: ignore[arg-type]
    assert info.value.phase == "query_extract" and info.value.tile_id is None
    assert "frame" in str(info.value)
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert record["phase"] == "query_extract" and record["frame_id"] == str(rig.rerank.frame_id)
    last = rig.health.last_update
    assert rig.health.update_count == 1 and last is not None and last.had_backbone_error
    assert fdr.of_kind("matcher.invalid_input") == []


@pytest.mark.parametrize("which", ["frame", "rerank_result", "calibration"])
def test_wrong_types_are_a_programming_error(fdr, logs, which):
    rig = ScriptedRig([S(100)], fdr)
    args = {"frame": rig.frame, "rerank_result": rig.rerank, "calibration": rig.calibration}
    args[which] = "not a DTO"
    with pytest.raises(InvalidInputError, match=which):
        rig.pipeline.match(**args)  # type: ignore[arg-type]
    assert [r["field"] for r in fdr.of_kind("matcher.invalid_input")] == [which]
    assert rig.health.update_count == 1


# -- the real engines ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def demo_matcher(
    engine_dir: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[CrossDomainMatcher, InMemoryFdr]]:
    settings = C3Settings(
        engines={"directory": engine_dir},
        fdr={"path": tmp_path_factory.mktemp("fdr") / "fdr.jsonl"},
    )
    fdr = InMemoryFdr()
    root = compose_root(
        settings, {**build_default_helpers(settings), "c13_fdr": fdr}, configure_logs=False
    )
    yield root.matcher, fdr
    root.close()


def test_real_engines_stale_rerank_and_missing_frame_then_a_fix(demo_matcher):
    matcher, fdr = demo_matcher
    frame, rerank, calibration = demo_inputs(DEMO)
    stale = RerankResult(uuid.UUID(int=2), rerank.candidates)  # made for the frame before
    with pytest.raises(InsufficientInliersError) as info:
        matcher.match(frame, stale, calibration)
    assert info.value.candidates_dropped == len(stale.candidates)
    assert fdr.of_kind("matcher.insufficient_inliers")[-1]["stale_rerank"] == str(stale.frame_id)
    with pytest.raises(MatcherBackboneError, match="query_extract"):
        matcher.match(None, stale, calibration)  # type: ignore[arg-type]
    result = matcher.match(frame, rerank, calibration)  # the next consistent frame: a fix
    assert result.frame_id == frame.frame_id and result.per_candidate
    assert result.per_candidate[0].inlier_count >= 60


def test_real_engines_a_closed_root_refuses_frames(engine_dir, tmp_path):
    """The default strategy's matcher is closed with its root: a frame after ``close()`` is
    refused instead of being matched with no recorder to keep its records."""
    settings = C3Settings(engines={"directory": engine_dir}, fdr={"path": tmp_path / "fdr.jsonl"})
    root = compose_root(settings, build_default_helpers(settings), configure_logs=False)
    root.close()
    frame, rerank, calibration = demo_inputs(DEMO)
    with pytest.raises(MatcherClosedError, match="disk_lightglue"):
        root.matcher.match(frame, rerank, calibration)
    assert [r["kind"] for r in read_fdr(tmp_path / "fdr.jsonl")] == []
