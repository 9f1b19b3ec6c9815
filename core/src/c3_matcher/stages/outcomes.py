"""The values that travel between the stages of the per-frame loop: a candidate's tile
features, a candidate kept (:class:`Survivor`) or dropped (:class:`Dropped`, named in the
records as a :class:`CandidateDrop`), the refine pass's record and what a frame's terminal
records report (:class:`FrameEvidence`). Query points of a ``Survivor``'s correspondences are
ORIGINAL frame px; tile points are the tile's px."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import CandidateMatchSet
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage

__all__ = [
    "CandidateDrop",
    "Dropped",
    "FrameEvidence",
    "GeometryRefusal",
    "RefineRecord",
    "Survivor",
    "TileFeatures",
]


@dataclass(frozen=True)
class TileFeatures:
    """A candidate tile's prepared image and features, and where they came from: ``stored``
    (a tile store's precomputed map features), ``cached`` (the tile cache) or ``extracted``.
    ``forget`` drops them from the tile cache (nothing for features it does not hold): called
    when they are refused or matching them fails, so the next frame extracts the tile anew."""

    source: str
    image: PreparedImage
    features: Features
    forget: Callable[[], None] = field(default=lambda: None, compare=False, repr=False)


@dataclass(frozen=True)
class Survivor:
    """A candidate kept: its match set, its index in the re-rank, the model mapping WORKING
    query px to tile px (``homography``: the RANSAC homography, or the prior's similarity when
    ``model`` is ``"similarity"``), the query turn it kept, its tile features (for the refine
    pass) and its step timings (ms)."""

    match_set: CandidateMatchSet
    input_index: int
    homography: NDArray[np.float64] | None
    rotation_deg: int
    tile: TileFeatures
    model: str = "homography"
    timings: dict[str, float] = field(default_factory=dict, compare=False)

    @property
    def source(self) -> str:
        return self.tile.source


@dataclass(frozen=True)
class GeometryRefusal:
    """A candidate refused by the geometric prior whatever its inliers; ``rotation_deg`` (the
    kept turn) only under rotation search."""

    tile_id: Any
    candidate_index: int
    inlier_count: int
    reason: str
    rotation_deg: int | None = None

    def as_record(self) -> dict[str, Any]:
        """The refusal as it appears in logs, FDR records and diagnostics."""
        return _record(self)


@dataclass(frozen=True)
class Dropped:
    """A candidate dropped: a backbone failure, zero inliers, or ``refusal`` on geometry."""

    input_index: int
    source: str
    timings: dict[str, float] = field(default_factory=dict, compare=False)
    refusal: GeometryRefusal | None = None


@dataclass(frozen=True)
class CandidateDrop:
    """A dropped candidate as a terminal FDR record names it: its input position, its tile id
    and why it was dropped (in the words ``c3-matcher match`` prints)."""

    candidate_index: int
    tile_id: Any
    reason: str

    def as_record(self) -> dict[str, Any]:
        """The drop as it appears in FDR records."""
        return _record(self)


@dataclass(frozen=True)
class RefineRecord:
    """What the refine pass did with the best candidate: its inliers before and after, whether
    the second pass was kept, and why not (``reason``) when it was not."""

    candidate_index: int
    inliers_before: int
    inliers_after: int = 0
    kept: bool = False
    reason: str | None = None

    def as_record(self) -> dict[str, Any]:
        """The refine pass as it appears in logs and FDR records."""
        return _record(self)


@dataclass(frozen=True)
class FrameEvidence:
    """What a frame's terminal records report besides its best candidate: the candidates in
    input order (where each one's features came from, its timings), how many were dropped, the
    refusals on geometry, whether the rotation search ran and the refine pass's record."""

    candidates_input: int
    sources: tuple[str, ...] = ()
    per_candidate_ms: tuple[dict[str, float], ...] = ()
    dropped: int = 0
    refused: tuple[GeometryRefusal, ...] = ()
    rotation_search: bool = False
    refine: RefineRecord | None = None

    @classmethod
    def of(
        cls,
        candidates: Sequence[Survivor | Dropped],
        *,
        rotation_search: bool,
        refine: RefineRecord | None,
    ) -> FrameEvidence:
        """The evidence of a frame whose every candidate was matched (``candidates`` in input
        order)."""
        dropped = [c for c in candidates if isinstance(c, Dropped)]
        return cls(
            len(candidates),
            tuple(c.source for c in candidates),
            tuple(c.timings for c in candidates),
            len(dropped),
            tuple(c.refusal for c in dropped if c.refusal is not None),
            rotation_search,
            refine,
        )

    def source_of(self, index: int) -> str:
        """Where candidate ``index``'s features came from (``none`` if it never got that far)."""
        return self.sources[index] if index < len(self.sources) else "none"


def _record(outcome: Any) -> dict[str, Any]:
    """A frozen outcome's fields in declaration order as a log / FDR row; an optional field
    (None: not set) is left out."""
    return {f.name: v for f in fields(outcome) if (v := getattr(outcome, f.name)) is not None}
