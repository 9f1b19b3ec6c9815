"""What a frame's terminal FDR record lets an investigator read from the FDR alone, in flight
where the log lines below WARNING are not kept: the matcher that produced it
(``matcher_label``), the frame's stage timings on a frame without a fix as on one with a fix,
and every input candidate by its input position: the kept ones' rows (``candidate_index``)
and the dropped ones with their tile id and why (``dropped``)."""

from __future__ import annotations

import dataclasses
import uuid

import pytest

from c3_matcher.errors import InsufficientInliersError, InvalidInputError
from c3_matcher.testing import ScriptedCandidate, ScriptedRig

S = ScriptedCandidate


def _tile(rig: ScriptedRig, index: int) -> list[float]:
    return rig.rerank.candidates[index].tile_id.as_list()


def test_the_success_record_names_its_matcher_and_each_candidate_by_input_position(fdr, logs):
    rig = ScriptedRig([S(80, 1.5), S(0), S(fail_extract=True), S(120, 1.1)], fdr)
    result = rig.match()
    (done,) = fdr.of_kind("matcher.frame_done")
    assert done["matcher_label"] == "fake_backend" == result.matcher_label
    rows = done["per_candidate"]  # ranked, each with its input position
    assert [r["candidate_index"] for r in rows] == result.diagnostics["input_index"] == [3, 0]
    assert [r["tile_id"] for r in rows] == [_tile(rig, 3), _tile(rig, 0)]
    dropped = done["dropped"]  # in input order, as many as candidates_dropped
    assert [(d["candidate_index"], d["tile_id"]) for d in dropped] == [
        (1, _tile(rig, 1)),
        (2, _tile(rig, 2)),
    ]
    assert len(dropped) == done["candidates_dropped"] == 2
    assert dropped[0]["reason"].startswith("no inliers after RANSAC (")
    assert dropped[1]["reason"].startswith("backbone error in disk_forward: ")


def test_the_no_fix_record_accounts_for_the_frame_as_the_success_record_does(fdr, logs):
    rig = ScriptedRig([S(0), S(59, 1.2), S(fail_match=True)], fdr)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["matcher_label"] == "fake_backend"
    timings = record["timings_ms"]
    assert {"query_preprocess", "query_extract", "total"} <= set(timings)
    stages = timings["query_preprocess"] + timings["query_extract"]
    stages += sum(v for t in record["per_candidate_timings_ms"] for v in t.values())
    assert 0 < stages <= timings["total"]  # its stages add up within its total
    assert [r["candidate_index"] for r in record["per_candidate"]] == [1]
    assert [(d["candidate_index"], d["tile_id"]) for d in record["dropped"]] == [
        (0, _tile(rig, 0)),
        (2, _tile(rig, 2)),
    ]
    assert record["dropped"][0]["reason"].startswith("no inliers after RANSAC (")
    assert record["dropped"][1]["reason"].startswith("backbone error in lightglue_match: ")
    # the fields readers of older records use are all still there, with their meaning
    assert (record["candidates_input"], record["candidates_dropped"]) == (3, 2)
    assert (record["best_inlier_count"], record["threshold"]) == (59, 60)
    assert len(record["per_candidate_timings_ms"]) == len(record["candidate_features"]) == 3


def test_a_frame_whose_every_candidate_has_no_inlier_names_each_of_them(fdr, logs):
    """The case the FDR said least about: every candidate dropped for zero inliers (a frame
    over a tile the re-ranker missed); their log lines are DEBUG."""
    rig = ScriptedRig([S(0), S(0)], fdr)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["per_candidate"] == [] and record["geometry_refused"] == []
    assert [(d["candidate_index"], d["tile_id"]) for d in record["dropped"]] == [
        (0, _tile(rig, 0)),
        (1, _tile(rig, 1)),
    ]


def test_the_no_fix_record_lists_its_candidates_best_first_as_the_success_record_does(fdr, logs):
    """An investigator reads ``per_candidate[0]`` as the best candidate: it was the first input
    candidate on a frame without a fix (9 inliers beside the best's 29)."""
    rig = ScriptedRig([S(9, 1.5), S(29, 1.1), S(29, 0.9), S(0)], fdr)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    rows = record["per_candidate"]
    assert [r["candidate_index"] for r in rows] == [2, 1, 0]  # inliers, then residual
    assert rows[0]["inlier_count"] == record["best_inlier_count"] == 29


def test_the_terminal_records_carry_the_frames_capture_time(fdr, logs):
    """How old a frame was when matched could not be read after a flight: ``captured_at_ns``
    was checked and then carried nowhere (not the result, the FDR or the logs)."""
    rig = ScriptedRig([S(80, 1.5)], fdr)
    rig.match()
    (done,) = fdr.of_kind("matcher.frame_done")
    assert done["captured_at_ns"] == rig.frame.captured_at_ns == 1
    stale = ScriptedRig([S(80, 1.5)], fdr)
    stale_rerank = dataclasses.replace(stale.rerank, frame_id=uuid.UUID(int=9))
    with pytest.raises(InsufficientInliersError):
        stale.pipeline.match(stale.frame, stale_rerank, stale.calibration)
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["captured_at_ns"] == 1


@pytest.mark.parametrize("captured", [2**63, 2**64, 10**30])
def test_a_capture_time_beyond_int64_nanoseconds_is_refused(fdr, captured: int) -> None:
    rig = ScriptedRig([S(80)], fdr)
    with pytest.raises(InvalidInputError, match="frame.captured_at_ns: exceeds int64 ns"):
        dataclasses.replace(rig.frame, captured_at_ns=captured)
