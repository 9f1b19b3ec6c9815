"""Steps 5 and 7: the survivors' best inlier count and their deterministic ranking (inliers
descending, then median residual ascending: ``c3_matcher.dto.ranking_key``; a stable order, so
input order breaks exact ties)."""

from __future__ import annotations

from collections.abc import Sequence

from c3_matcher.dto import ranking_key
from c3_matcher.stages.outcomes import Survivor

__all__ = ["best_inlier_count", "ranked", "top"]


def best_inlier_count(survivors: Sequence[Survivor]) -> int:
    """The most inliers of any survivor; 0 without one."""
    return max((s.match_set.inlier_count for s in survivors), default=0)


def ranked(survivors: Sequence[Survivor]) -> list[Survivor]:
    """The survivors best first (stable)."""
    return sorted(survivors, key=lambda s: ranking_key(s.match_set))


def top(survivors: Sequence[Survivor]) -> Survivor:
    """The best-ranked survivor (the first of equals in input order); ``survivors`` not empty."""
    return min(survivors, key=lambda s: ranking_key(s.match_set))
