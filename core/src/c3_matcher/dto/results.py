"""What the matcher gives out: RANSAC results, per-candidate match sets, the frame's result and
the matcher's health. Correspondences are float32 (I, 4) = (x_query, y_query, x_tile, y_tile)."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.dto.geo import TileId


@dataclass(frozen=True, slots=True)
class RansacResult:
    """Output of ``RansacFilter.filter``.

    ``inlier_correspondences`` float32 (I, 4) = (x_query, y_query, x_tile, y_tile) in the
    coordinates that were filtered; ``per_candidate_residual_px`` is the MEDIAN reprojection
    error of the inliers in tile pixels, 0.0 when there are none; ``homography`` maps
    query to tile points (float64 (3, 3)) or is None; ``inlier_mask`` bool (M,) over the input.
    """

    inlier_correspondences: NDArray[np.float32]
    ransac_outlier_count: int
    per_candidate_residual_px: float
    homography: NDArray[np.float64] | None
    inlier_mask: NDArray[np.bool_]

    def __post_init__(self) -> None:
        v.array(
            self.inlier_correspondences,
            "ransac.inlier_correspondences",
            dtype=np.float32,
            shape=(None, 4),
        )
        v.non_negative_int(self.ransac_outlier_count, "ransac.ransac_outlier_count")
        v.finite_float(self.per_candidate_residual_px, "ransac.per_candidate_residual_px", low=0)
        if self.homography is not None:
            v.array(self.homography, "ransac.homography", dtype=np.float64, shape=(3, 3))
        v.array(self.inlier_mask, "ransac.inlier_mask", dtype=np.bool_, ndim=1)

    @property
    def inlier_count(self) -> int:
        return int(self.inlier_correspondences.shape[0])


@dataclass(frozen=True, slots=True)
class CandidateMatchSet:
    """One surviving candidate: its RANSAC inliers and residual statistics.

    ``inlier_correspondences`` float32 (I, 4) = (x_query, y_query, x_tile, y_tile): the query
    point in the ORIGINAL frame's pixels (distortion included), the tile point in the tile's
    pixels; I == ``inlier_count``. ``per_candidate_residual_px`` is the
    median inlier residual in tile pixels.
    """

    tile_id: TileId
    inlier_count: int
    inlier_correspondences: NDArray[np.float32]
    ransac_outlier_count: int
    per_candidate_residual_px: float

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.tile_id, TileId),
            "candidate_match_set.tile_id",
            f"expected TileId, got {type(self.tile_id).__name__}",
        )
        n = v.non_negative_int(self.inlier_count, "candidate_match_set.inlier_count")
        corr = v.array(
            self.inlier_correspondences,
            "candidate_match_set.inlier_correspondences",
            dtype=np.float32,
            shape=(n, 4),
        )
        object.__setattr__(self, "inlier_correspondences", v.frozen_copy(corr))
        v.non_negative_int(self.ransac_outlier_count, "candidate_match_set.ransac_outlier_count")
        v.finite_float(
            self.per_candidate_residual_px, "candidate_match_set.per_candidate_residual_px", low=0
        )

    def same_content(self, other: CandidateMatchSet) -> bool:
        """Bit-for-bit equality of every field."""
        return (
            self.tile_id == other.tile_id
            and self.inlier_count == other.inlier_count
            and self.ransac_outlier_count == other.ransac_outlier_count
            and self.per_candidate_residual_px == other.per_candidate_residual_px
            and self.inlier_correspondences.tobytes() == other.inlier_correspondences.tobytes()
        )


def ranking_key(candidate: CandidateMatchSet) -> tuple[int, float]:
    """inlier count descending, then median residual ascending (a stable sort keeps
    the input order on ties)."""
    return (-candidate.inlier_count, candidate.per_candidate_residual_px)


@dataclass(frozen=True, slots=True)
class MatchResult:
    """The matcher's output for one frame; the result contract's invariants are checked here.
    ``matched_at`` is in ns on the matcher's clock (``Clock.monotonic_ns``)."""

    frame_id: uuid.UUID
    per_candidate: tuple[CandidateMatchSet, ...]
    best_candidate_idx: int
    reprojection_residual_px: float
    matched_at: int
    matcher_label: str
    candidates_input: int
    candidates_dropped: int
    diagnostics: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        per = tuple(self.per_candidate)
        object.__setattr__(self, "per_candidate", per)
        v.require(len(per) >= 1, "match_result.per_candidate", "must hold at least one survivor")
        n_in = v.non_negative_int(self.candidates_input, "match_result.candidates_input")
        v.require(
            len(per) <= n_in,
            "match_result.per_candidate",
            f"{len(per)} survivors > {n_in} input candidates",
        )
        v.require(
            self.candidates_dropped == n_in - len(per),
            "match_result.candidates_dropped",
            f"must equal candidates_input - len(per_candidate) = {n_in - len(per)}",
        )
        v.require(
            self.best_candidate_idx == 0,
            "match_result.best_candidate_idx",
            "must be 0: per_candidate is sorted best first",
        )
        v.require(
            self.reprojection_residual_px == per[0].per_candidate_residual_px,
            "match_result.reprojection_residual_px",
            "must equal per_candidate[0].per_candidate_residual_px",
        )
        keys = [ranking_key(c) for c in per]
        v.require(
            keys == sorted(keys),
            "match_result.per_candidate",
            "must be sorted by inlier_count desc, residual asc",
        )
        v.non_negative_int(self.matched_at, "match_result.matched_at")
        v.require(
            isinstance(self.matcher_label, str) and bool(self.matcher_label),
            "match_result.matcher_label",
            "must be a non-empty string",
        )

    @property
    def best(self) -> CandidateMatchSet:
        return self.per_candidate[self.best_candidate_idx]


@dataclass(frozen=True, slots=True)
class MatcherHealth:
    """Rolling health of the matcher: consecutive low-inlier frames, mean best inliers over 60 s."""

    consecutive_low_inlier: int
    mean_inliers_60s: float
