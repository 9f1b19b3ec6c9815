"""What a frame's terminal FDR record (``matcher.frame_done``, ``matcher.insufficient_inliers``)
says: its fields, declared once (``TerminalRecord``, whose keys are the core's own:
``TERMINAL_RECORD_FIELDS``, which a backend's provenance may not name), and what it says of its
candidates: the kept ones' rows, where each one's features came from, the refusals on geometry,
the dropped ones and why, the rotation search and refine pass when they ran, and the
per-candidate timings."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final, TypedDict

from c3_matcher.stages.outcomes import CandidateDrop, FrameEvidence, Survivor
from c3_matcher.stages.query import QUERY_ROTATIONS_DEG

__all__ = [
    "TERMINAL_RECORD_FIELDS",
    "CandidatesRecord",
    "TerminalRecord",
    "candidates_record",
    "per_candidate_records",
]


class CandidatesRecord(TypedDict, total=False):
    """What a terminal record says of the candidates (``candidates_record``); the rotation
    search's and refine pass's fields only when they ran."""

    per_candidate: list[dict[str, Any]]
    candidate_features: list[str]
    geometry_refused: list[dict[str, Any]]
    dropped: list[dict[str, Any]]
    rotation_search: bool
    rotations_deg: list[int]
    refine: dict[str, Any]
    per_candidate_timings_ms: list[dict[str, float]]


class TerminalRecord(CandidatesRecord, total=False):
    """Every field the core writes in a frame's success or no-fix record; a backend's
    provenance fills the rest, minus these (``provenance_error``: its provenance could not be
    read)."""

    frame_id: Any
    captured_at_ns: int
    stale_rerank: Any
    candidates_input: int
    candidates_dropped: int
    best_inlier_count: int
    threshold: int
    best_residual_px: float
    best_tile_id: Any
    best_homography: Any
    query_rectification: Any
    matcher_label: str
    ambiguous: dict[str, Any]
    timings_ms: dict[str, float]
    provenance_error: str


TERMINAL_RECORD_FIELDS: Final = TerminalRecord.__required_keys__ | TerminalRecord.__optional_keys__
"""The keys of a terminal record that are the core's: a backend's provenance naming one is
left out of the record (``stages.provenance``)."""


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
) -> CandidatesRecord:
    """What a terminal FDR record says of the candidates, success or not: the ``kept`` ones'
    figures, where each one's features came from, the refusals on geometry (whatever their
    inliers), every dropped one and why, the rotation search and refine pass when they ran,
    and each one's timings (the lists without an index in input order)."""
    record: CandidatesRecord = {
        "per_candidate": per_candidate_records(evidence, kept),
        "candidate_features": list(evidence.sources),
        "geometry_refused": [r.as_record() for r in evidence.refused],
        "dropped": [d.as_record() for d in drops],
    }
    if evidence.rotation_search:
        record["rotation_search"] = True
        record["rotations_deg"] = list(QUERY_ROTATIONS_DEG)
    if evidence.refine is not None:
        record["refine"] = evidence.refine.as_record()
    record["per_candidate_timings_ms"] = list(evidence.per_candidate_ms)
    return record
