"""What a frame without a fix raises and how its ERROR line says it: ambiguous, or short of
inliers (``FrameRecorder.insufficient``)."""

from __future__ import annotations

from typing import Any

from c3_matcher.errors import AmbiguousMatchError, InsufficientInliersError, refused_words
from c3_matcher.stages.ambiguity import Ambiguity
from c3_matcher.stages.outcomes import FrameEvidence

__all__ = ["no_fix_error", "no_fix_words"]


def no_fix_error(
    frame_id: Any,
    evidence: FrameEvidence,
    best_count: int,
    threshold: int,
    label: str,
    ambiguity: Ambiguity | None,
) -> InsufficientInliersError:
    """The error a frame without a fix raises: ambiguous, or short of inliers."""
    facts = (frame_id, best_count, threshold, evidence.candidates_input, evidence.dropped)
    if ambiguity is not None:
        return AmbiguousMatchError(*facts, label, ambiguity=ambiguity.reason)
    refused = tuple((r.inlier_count, r.reason) for r in evidence.refused)
    return InsufficientInliersError(*facts, label, refused)


def no_fix_words(
    error: InsufficientInliersError,
    evidence: FrameEvidence,
    threshold: int,
    ambiguity: Ambiguity | None,
) -> tuple[str, str]:
    """What the no-fix ERROR line says happened, and its facts."""
    if ambiguity is not None:
        return "ambiguous match, no fix", ambiguity.reason
    return (
        "insufficient inliers on all candidates",
        f"best={error.best_inlier_count} < {threshold}; {evidence.dropped} of "
        f"{evidence.candidates_input} candidates dropped{refused_words(error.geometry_refused)}",
    )
