"""The matcher's data transfer objects, frozen and validated at construction.

Conventions: pixels are 0-based, origin at the centre of the top-left pixel,
points in (x, y) order; angles in radians; attitude is aerospace Z-Y-X (yaw, pitch, roll) of the
NED body frame, yaw from true north. Images are ``uint8`` RGB ``(H, W, 3)`` or grey ``(H, W)``.

The classes live by concern in ``geo`` (tile id, attitude), ``camera`` (frame, calibration),
``candidates`` (the re-ranker's output and the tile handle it carries) and ``results`` (RANSAC,
match sets, the frame's result, health); import them from here.
"""

from __future__ import annotations

from c3_matcher.dto.camera import MAX_HEIGHT_ABOVE_GROUND_M, CameraCalibration, NavCameraFrame
from c3_matcher.dto.candidates import RerankCandidate, RerankResult, TilePixelsHandle
from c3_matcher.dto.geo import WEB_MERCATOR_EQUATOR_M_PER_PX, Attitude, TileId
from c3_matcher.dto.results import (
    CandidateMatchSet,
    MatcherHealth,
    MatchResult,
    RansacResult,
    ranking_key,
)

__all__ = [
    "MAX_HEIGHT_ABOVE_GROUND_M",
    "WEB_MERCATOR_EQUATOR_M_PER_PX",
    "Attitude",
    "CameraCalibration",
    "CandidateMatchSet",
    "MatchResult",
    "MatcherHealth",
    "NavCameraFrame",
    "RansacResult",
    "RerankCandidate",
    "RerankResult",
    "TileId",
    "TilePixelsHandle",
    "ranking_key",
]
