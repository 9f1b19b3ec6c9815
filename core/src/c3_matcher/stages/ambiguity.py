"""Step 7's check that the best candidate's place is the only one the frame supports.

Ranking takes the candidate with the most inliers. Where another candidate has nearly as many
and puts the frame somewhere else, the frame matches two places: texture that repeats at one
orientation and scale (rows of like roofs, greenhouses, a field grid, a planned district) passes
RANSAC and the geometric prior on a tile of another place as well as on the true one, and which
one wins is chance. Such a frame gets no fix (:class:`~c3_matcher.errors.AmbiguousMatchError`,
an ``InsufficientInliersError``: the caller falls back as for any frame without one).

Two candidates agree when the best one's inlier query points, each mapped through both
candidates' fitted homographies onto the ground, land within :data:`AGREE_PX` px of the best
tile's ground sample distance (median over the points): adjacent or overlapping tiles of one
place, other dates or zooms of it, agree. A candidate whose id is no place (a placeholder) or
whose inliers fit no homography cannot be placed, and so contradicts nothing.

Why the numbers hold beyond the shipped flights (``scripts/ambiguity_ratios.py EVAL_OUT``):
- :data:`AMBIGUITY_RATIO` 0.5: a second place with half the best's support is no longer a
  distinctive match, the sense of Lowe's ratio test applied to places. On the shipped flights a
  candidate placing the frame elsewhere reached at most 0.09 of the best's inliers, for each
  strategy (DISK 0.07, ALIKED 0.04, XFeat 0.09, SIFT 0.05), so no fix there is refused; on
  rendered repetitive texture with the true tile absent, the wrong fixes' rivals reached
  0.54-0.98 (ALIKED) and 0.65-0.98 (DISK), the right fixes' at most 0.47.
- :data:`AGREE_PX` 16: candidates of one place measured at most 8 px apart (2 px typical), for
  every strategy; two placements closer than 16 px change the fix by less than that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration, RerankCandidate
from c3_matcher.georef import fit_query_to_tile, haversine_m, is_georeferenced, tile_px_to_lonlat
from c3_matcher.stages.outcomes import Survivor

__all__ = ["AGREE_PX", "AMBIGUITY_RATIO", "Ambiguity", "ambiguity"]

AMBIGUITY_RATIO = 0.5
"""A rival with at least this share of the best candidate's inliers must agree on the place."""

AGREE_PX = 16.0
"""Two placements within this many px of the best tile's ground sample distance agree."""


@dataclass(frozen=True, slots=True)
class Ambiguity:
    """The best candidate and a rival placing the frame ``distance_m`` from it (input indices,
    inlier counts)."""

    best_index: int
    best_inliers: int
    rival_index: int
    rival_inliers: int
    distance_m: float

    @property
    def reason(self) -> str:
        """The ambiguity in words, for the error, the log and the record."""
        share = self.rival_inliers / self.best_inliers
        return (
            f"candidate {self.rival_index} ({self.rival_inliers} inliers, {share:.2f} of the "
            f"best's) places the frame {self.distance_m:.0f} m from candidate "
            f"{self.best_index} ({self.best_inliers} inliers)"
        )

    def as_record(self) -> dict[str, Any]:
        """The ambiguity as logs and flight-data records carry it."""
        return {
            "best_index": self.best_index,
            "best_inliers": self.best_inliers,
            "rival_index": self.rival_index,
            "rival_inliers": self.rival_inliers,
            "distance_m": self.distance_m,
            "reason": self.reason,
        }


def ambiguity(
    ranked: Sequence[Survivor],
    candidates: Sequence[RerankCandidate],
    calibration: CameraCalibration,
) -> Ambiguity | None:
    """The first rival of the best of ``ranked`` (best first) with :data:`AMBIGUITY_RATIO` of
    its inliers that places the frame farther than :data:`AGREE_PX` from it; None when every
    such rival agrees (or none has that many)."""
    best = ranked[0]
    most = best.match_set.inlier_count
    rivals = [s for s in ranked[1:] if s.match_set.inlier_count >= AMBIGUITY_RATIO * most]
    if not rivals:
        return None
    query = cam.undistort_points(best.match_set.inlier_correspondences[:, 0:2], calibration)
    here = _placed(best, candidates, calibration, query)
    if here is None:
        return None
    best_gsd = _gsd_m(candidates[best.input_index])
    for rival in rivals:
        there = _placed(rival, candidates, calibration, query)
        if there is None:
            continue
        apart = haversine_m(here, there)
        distance = float(np.median(apart[np.isfinite(apart)])) if np.isfinite(apart).any() else 0
        if distance > AGREE_PX * best_gsd:
            return Ambiguity(
                best.input_index, most, rival.input_index, rival.match_set.inlier_count, distance
            )
    return None


def _placed(
    survivor: Survivor,
    candidates: Sequence[RerankCandidate],
    calibration: CameraCalibration,
    undistorted: F64,
) -> F64 | None:
    """(N, 2) lon/lat where ``survivor``'s fitted homography puts the UNDISTORTED query points;
    None when its tile id is no place or its inliers fit none."""
    candidate = candidates[survivor.input_index]
    if not is_georeferenced(candidate.tile_id):
        return None
    hom = fit_query_to_tile(survivor.match_set.inlier_correspondences, calibration)
    if hom is None:
        return None
    tile_px = cam.apply_homography(hom, undistorted)
    size = survivor.tile.image.working_size
    return tile_px_to_lonlat(candidate.tile_id, size, tile_px, candidate.gsd_m_per_px)


def _gsd_m(candidate: RerankCandidate) -> float:
    """The candidate tile's ground sample distance (m/px): given, else its zoom's."""
    gsd = candidate.gsd_m_per_px
    return float(gsd) if gsd is not None else candidate.tile_id.web_mercator_gsd_m()
