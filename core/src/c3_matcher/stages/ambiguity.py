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
place, other dates or zooms of it, agree. A candidate whose id is no place (a placeholder, a
latitude beyond web mercator's) or whose inliers fit no homography cannot be placed, and so
contradicts nothing.

Why the numbers hold beyond the shipped flights (``scripts/ambiguity_ratios.py DATA EVAL_OUT``):
- :data:`AMBIGUITY_RATIO` 0.5: a second place with half the best's support is no longer a
  distinctive match, the sense of Lowe's ratio test applied to places. On the shipped flights a
  rival placing the frame elsewhere reached at most 0.09 of the best's inliers, for each
  strategy (DISK 0.07, ALIKED 0.04, XFeat 0.09; SIFT's rivals were all of the best's place), so
  no fix there is refused; on rendered repetitive texture with the true tile absent, the wrong
  fixes' rivals reached 0.54-0.98 (ALIKED) and 0.65-0.98 (DISK), the right fixes' at most 0.47.
- :data:`AGREE_PX` 16: rivals of the best's place were at most 12 px from it, under 3 px for
  every one with 0.15 of its inliers or more, for every strategy; two placements closer than
  16 px change the fix by less than that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher import camera as cam
from c3_matcher.dto import CameraCalibration, RerankCandidate, TileId
from c3_matcher.georef import fit_query_to_tile, haversine_m, is_georeferenced, tile_px_to_lonlat
from c3_matcher.stages.outcomes import Survivor
from c3_matcher.tilestore.geo import MERCATOR_MAX_LAT

__all__ = ["AGREE_PX", "AMBIGUITY_RATIO", "Ambiguity", "Placed", "ambiguity", "apart_m"]

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
        """The ambiguity as logs and flight-data records carry it: its fields and reason."""
        return {**asdict(self), "reason": self.reason}


@dataclass(frozen=True, slots=True)
class Placed:
    """A candidate's inlier rows (x_query, y_query, x_tile, y_tile; ORIGINAL px) and where its
    tile lies: its id, its (width, height) and its ground sample distance when given (None: a
    store window, :mod:`c3_matcher.georef`)."""

    rows: NDArray[np.float32]
    tile_id: TileId
    size: tuple[int, int]
    gsd_m: float | None

    @property
    def tile_gsd_m(self) -> float:
        """The tile's ground sample distance (m/px): given, else its zoom's."""
        return float(self.gsd_m) if self.gsd_m is not None else self.tile_id.web_mercator_gsd_m()


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
    here = _placed(best, candidates)
    for rival in rivals:
        distance = apart_m(here, _placed(rival, candidates), calibration)
        if distance is not None and distance > AGREE_PX * here.tile_gsd_m:
            return Ambiguity(
                best.input_index, most, rival.input_index, rival.match_set.inlier_count, distance
            )
    return None


def apart_m(best: Placed, rival: Placed, calibration: CameraCalibration | None) -> float | None:
    """How far apart (m) ``best`` and ``rival`` place the frame: the median over the best's
    inlier query points of the distance between where each one's fitted homography puts it;
    None when either id is no place or either's inliers fit none."""
    if not (_a_place(best.tile_id) and _a_place(rival.tile_id)):
        return None
    h_best, h_rival = (fit_query_to_tile(p.rows, calibration) for p in (best, rival))
    if h_best is None or h_rival is None:
        return None
    rows = np.asarray(best.rows, dtype=np.float64).reshape(-1, 4)[:, 0:2]
    query = rows if calibration is None else cam.undistort_points(rows, calibration)
    here = tile_px_to_lonlat(
        best.tile_id, best.size, cam.apply_homography(h_best, query), best.gsd_m
    )
    there = tile_px_to_lonlat(
        rival.tile_id, rival.size, cam.apply_homography(h_rival, query), rival.gsd_m
    )
    apart = haversine_m(here, there)
    finite = apart[np.isfinite(apart)]
    return float(np.median(finite)) if finite.size else None


def _a_place(tile_id: TileId) -> bool:
    """``tile_id`` names a place on the web-mercator map: no placeholder, no latitude beyond
    the map's (a re-ranker's id there still gets its fix; it only cannot be compared)."""
    return is_georeferenced(tile_id) and abs(tile_id.lat) <= MERCATOR_MAX_LAT


def _placed(survivor: Survivor, candidates: Sequence[RerankCandidate]) -> Placed:
    """``survivor``'s inliers and its candidate tile's place."""
    candidate = candidates[survivor.input_index]
    rows = survivor.match_set.inlier_correspondences
    return Placed(rows, candidate.tile_id, survivor.tile.image.working_size, candidate.gsd_m_per_px)
