"""What a frame's terminal FDR record (``matcher.frame_done``, ``matcher.insufficient_inliers``)
says of its candidates: the kept ones' rows, where each one's features came from, the refusals
on geometry, the dropped ones and why, the rotation search and refine pass when they ran, and the
per-candidate timings."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from c3_matcher.stages.outcomes import CandidateDrop, FrameEvidence, Survivor
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG

__all__ = ["candidates_record", "per_candidate_records"]


def per_candidate_records(
    evidence: FrameEvidence, survivors: Sequence[Survivor]
) -> list[dict[str, Any]]:
    """The survivors as FDR rows, each with its input position (``candidate_index``);
    ``rotation_deg`` (the kept turn) only under rotation search and ``model`` only for a
    candidate kept on the prior's similarity, so other records are as they were."""
    rows: list[dict[str, Any]] = []
    for s in survivors:
        row: dict[str, Any] = {
            "candidate_index": s.input_index,
            "tile_id": s.match_set.tile_id,
            "inlier_count": s.match_set.inlier_count,
            "residual_px": s.match_set.per_candidate_residual_px,
            "features": evidence.source_of(s.input_index),
        }
        if evidence.rotation_search:
            row["rotation_deg"] = s.rotation_deg
        if s.model != "homography":
            row["model"] = s.model
        rows.append(row)
    return rows


def candidates_record(
    evidence: FrameEvidence, kept: Sequence[Survivor], drops: Sequence[CandidateDrop]
) -> dict[str, Any]:
    """What a terminal FDR record says of the candidates, success or not: the ``kept`` ones'
    figures, where each one's features came from, the refusals on geometry (whatever their
    inliers), every dropped one and why, the rotation search and refine pass when they ran,
    and each one's timings (the lists without an index in input order)."""
    return {
        "per_candidate": per_candidate_records(evidence, kept),
        "candidate_features": list(evidence.sources),
        "geometry_refused": [r.as_record() for r in evidence.refused],
        "dropped": [d.as_record() for d in drops],
        **_rotation_record(evidence),
        **_refine_record(evidence),
        "per_candidate_timings_ms": list(evidence.per_candidate_ms),
    }


def _rotation_record(evidence: FrameEvidence) -> dict[str, Any]:
    """``rotation_search`` and the turns tried, in a terminal FDR record of a frame that ran
    the search; nothing otherwise."""
    if not evidence.rotation_search:
        return {}
    return {"rotation_search": True, "rotations_deg": list(QUERY_ROTATIONS_DEG)}


def _refine_record(evidence: FrameEvidence) -> dict[str, Any]:
    """The refine pass's record for the terminal FDR record: only when it ran."""
    return {"refine": evidence.refine.as_record()} if evidence.refine is not None else {}
