"""The matcher's data transfer objects, frozen and validated at construction.

Conventions: pixels are 0-based, origin at the centre of the top-left pixel,
points in (x, y) order; angles in radians; attitude is aerospace Z-Y-X (yaw, pitch, roll) of the
NED body frame, yaw from true north. Images are ``uint8`` RGB ``(H, W, 3)`` or grey ``(H, W)``.
"""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.errors import InvalidInputError

if TYPE_CHECKING:
    from c3_matcher.protocols import TilePixelsHandle

__all__ = [
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
]

WEB_MERCATOR_EQUATOR_M_PER_PX = 156543.03392804097  # 256-px tiles, zoom 0
MAX_HEIGHT_ABOVE_GROUND_M = 100_000.0  # above this a "height" is a units or sensor error
MAX_K_CONDITION = 1e12  # a K this ill-conditioned cannot be inverted reliably


@dataclass(frozen=True, slots=True)
class TileId:
    """Composite tile id (zoomLevel, lat, lon): the tile centre, WGS84 degrees."""

    zoom: int
    lat: float
    lon: float

    def __post_init__(self) -> None:
        if isinstance(self.zoom, bool) or not isinstance(self.zoom, int):
            raise InvalidInputError("tile_id.zoom", f"expected an int, got {self.zoom!r}")
        v.require(0 <= self.zoom <= 30, "tile_id.zoom", f"must be in [0, 30], got {self.zoom}")
        object.__setattr__(self, "lat", v.finite_float(self.lat, "tile_id.lat", low=-90, high=90))
        object.__setattr__(self, "lon", v.finite_float(self.lon, "tile_id.lon", low=-180, high=180))

    @classmethod
    def parse(cls, text: str) -> TileId:
        """Parse ``"ZOOM,LAT,LON"`` (the CLI form)."""
        parts = text.split(",")
        if len(parts) != 3:
            raise InvalidInputError("tile_id", f"expected ZOOM,LAT,LON, got {text!r}")
        try:
            return cls(int(parts[0]), float(parts[1]), float(parts[2]))
        except ValueError as exc:
            raise InvalidInputError("tile_id", f"cannot parse {text!r}: {exc}") from exc

    def web_mercator_gsd_m(self, tile_size_px: int = 256) -> float:
        """Ground sample distance (m/px) of a web-mercator tile of this zoom at this latitude."""
        scale = 256.0 / tile_size_px
        return (
            WEB_MERCATOR_EQUATOR_M_PER_PX
            * scale
            * math.cos(math.radians(self.lat))
            / (2**self.zoom)
        )

    def as_list(self) -> list[float | int]:
        return [self.zoom, self.lat, self.lon]

    def __str__(self) -> str:
        return f"{self.zoom},{self.lat:.7f},{self.lon:.7f}"


@dataclass(frozen=True, slots=True)
class Attitude:
    """Vehicle attitude in radians: Z-Y-X (yaw, pitch, roll), NED body frame, yaw from north."""

    roll: float
    pitch: float
    yaw: float

    def __post_init__(self) -> None:
        half_pi = math.pi / 2
        object.__setattr__(
            self, "roll", v.finite_float(self.roll, "attitude.roll", low=-half_pi, high=half_pi)
        )
        object.__setattr__(
            self, "pitch", v.finite_float(self.pitch, "attitude.pitch", low=-half_pi, high=half_pi)
        )
        object.__setattr__(
            self,
            "yaw",
            v.finite_float(self.yaw, "attitude.yaw", low=-2 * math.pi, high=2 * math.pi),
        )

    @classmethod
    def from_degrees(cls, roll: float, pitch: float, yaw: float) -> Attitude:
        return cls(math.radians(roll), math.radians(pitch), math.radians(yaw))


def _check_image(image: object, field_name: str) -> NDArray[np.uint8]:
    arr = v.array(image, field_name, dtype=np.uint8)
    v.require(
        arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3),
        field_name,
        f"expected (H, W) or (H, W, 3), got {arr.shape}",
    )
    v.require(
        arr.shape[0] >= 16 and arr.shape[1] >= 16,
        field_name,
        f"image too small: {arr.shape[1]}x{arr.shape[0]} px (minimum 16x16)",
    )
    return arr


@dataclass(frozen=True, slots=True)
class NavCameraFrame:
    """One nav-camera frame (C1): the raw (distorted) image and what is known of the pose.

    ``image`` is uint8 RGB (H, W, 3) or grey (H, W), as captured. ``captured_at_ns`` is the
    monotonic capture time. ``attitude`` and ``height_above_ground_m`` are optional; without
    attitude no rectification happens, without height no GSD scaling.
    """

    frame_id: uuid.UUID
    image: NDArray[np.uint8]
    captured_at_ns: int
    attitude: Attitude | None = None
    height_above_ground_m: float | None = None

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.frame_id, uuid.UUID),
            "frame.frame_id",
            f"expected uuid.UUID, got {type(self.frame_id).__name__}",
        )
        # a private read-only copy: the caller's buffer may be reused by the camera driver
        object.__setattr__(self, "image", v.frozen_copy(_check_image(self.image, "frame.image")))
        v.non_negative_int(self.captured_at_ns, "frame.captured_at_ns")
        v.require(
            self.attitude is None or isinstance(self.attitude, Attitude),
            "frame.attitude",
            f"expected Attitude or None, got {type(self.attitude).__name__}",
        )
        if self.height_above_ground_m is not None:
            h = v.finite_float(self.height_above_ground_m, "frame.height_above_ground_m")
            v.require(h > 0, "frame.height_above_ground_m", f"must be > 0, got {h}")
            v.require(
                h <= MAX_HEIGHT_ABOVE_GROUND_M,
                "frame.height_above_ground_m",
                f"must be <= {MAX_HEIGHT_ABOVE_GROUND_M:g} m (a UAV's height above ground), "
                f"got {h:g}",
            )


@dataclass(frozen=True, slots=True)
class CameraCalibration:
    """Intrinsics of the nav camera (C5 artifact).

    ``K`` float64 (3, 3) in pixels; ``distortion`` float64 (N,) OpenCV coefficients
    (k1, k2, p1, p2[, k3[, ...]]), N in {0, 4, 5, 8, 12, 14}; ``image_size`` (width, height) px;
    ``camera_to_body`` float64 (3, 3) rotation taking camera-frame vectors to the NED body frame,
    or None for the default mount (straight down, image top towards the nose).
    """

    K: NDArray[np.float64]
    distortion: NDArray[np.float64]
    image_size: tuple[int, int]
    camera_to_body: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        k = v.frozen_copy(v.array(self.K, "calibration.K", dtype=np.float64, shape=(3, 3)))
        v.require(k[0, 0] > 0 and k[1, 1] > 0, "calibration.K", "focal lengths must be > 0")
        v.require(
            bool(np.allclose(k[2], [0.0, 0.0, 1.0])), "calibration.K", "last row must be [0, 0, 1]"
        )
        with np.errstate(all="ignore"):
            cond = float(np.linalg.cond(k))
        v.require(
            math.isfinite(cond) and cond < MAX_K_CONDITION,
            "calibration.K",
            f"is singular or ill-conditioned (condition number {cond:.3g})",
        )
        object.__setattr__(self, "K", k)
        dist = v.frozen_copy(
            v.array(self.distortion, "calibration.distortion", dtype=np.float64, ndim=1)
        )
        v.require(
            dist.shape[0] in (0, 4, 5, 8, 12, 14),
            "calibration.distortion",
            f"expected 0, 4, 5, 8, 12 or 14 coefficients, got {dist.shape[0]}",
        )
        object.__setattr__(self, "distortion", dist)
        size = tuple(self.image_size)
        v.require(
            len(size) == 2 and all(isinstance(s, int) and s > 0 for s in size),
            "calibration.image_size",
            f"expected (width, height) > 0, got {self.image_size}",
        )
        object.__setattr__(self, "image_size", size)
        if self.camera_to_body is not None:
            r = v.frozen_copy(
                v.array(
                    self.camera_to_body,
                    "calibration.camera_to_body",
                    dtype=np.float64,
                    shape=(3, 3),
                )
            )
            v.require(
                bool(np.allclose(r @ r.T, np.eye(3), atol=1e-6))
                and bool(np.isclose(np.linalg.det(r), 1.0, atol=1e-6)),
                "calibration.camera_to_body",
                "must be a rotation matrix",
            )
            object.__setattr__(self, "camera_to_body", r)

    @classmethod
    def pinhole(
        cls, width: int, height: int, focal_px: float, distortion: tuple[float, ...] = ()
    ) -> CameraCalibration:
        k = np.array(
            [[focal_px, 0, (width - 1) / 2], [0, focal_px, (height - 1) / 2], [0, 0, 1]],
            dtype=np.float64,
        )
        return cls(k, np.array(distortion, dtype=np.float64), (width, height))


@dataclass(frozen=True, slots=True)
class RerankCandidate:
    """One candidate tile proposed by C2.5.

    ``tile_pixels_handle`` references the tile's encoded bytes (page-cache backed) and decodes on
    demand; ``gsd_m_per_px`` is the tile's ground sample distance when known, else the
    web-mercator GSD of ``tile_id`` is assumed.
    """

    tile_id: TileId
    score: float
    tile_pixels_handle: TilePixelsHandle
    gsd_m_per_px: float | None = None

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.tile_id, TileId),
            "candidate.tile_id",
            f"expected TileId, got {type(self.tile_id).__name__}",
        )
        object.__setattr__(self, "score", v.finite_float(self.score, "candidate.score"))
        missing = [
            m
            for m in ("encoded", "decode")
            if not callable(getattr(self.tile_pixels_handle, m, None))
        ]
        v.require(
            not missing,
            "candidate.tile_pixels_handle",
            "expected a TilePixelsHandle (encoded() and decode()), "
            f"{type(self.tile_pixels_handle).__name__} lacks {', '.join(missing)}()",
        )
        if self.gsd_m_per_px is not None:
            g = v.finite_float(self.gsd_m_per_px, "candidate.gsd_m_per_px")
            v.require(g > 0, "candidate.gsd_m_per_px", f"must be > 0, got {g}")

    def ground_sample_distance_m(self) -> float:
        if self.gsd_m_per_px is not None:
            return float(self.gsd_m_per_px)
        return self.tile_id.web_mercator_gsd_m()


@dataclass(frozen=True, slots=True)
class RerankResult:
    """C2.5's output: the frame's top-N candidate tiles, best first."""

    frame_id: uuid.UUID
    candidates: tuple[RerankCandidate, ...]

    def __post_init__(self) -> None:
        v.require(
            isinstance(self.frame_id, uuid.UUID),
            "rerank_result.frame_id",
            f"expected uuid.UUID, got {type(self.frame_id).__name__}",
        )
        cands = tuple(self.candidates)
        v.require(len(cands) >= 1, "rerank_result.candidates", "must hold at least one candidate")
        for i, c in enumerate(cands):
            v.require(
                isinstance(c, RerankCandidate),
                f"rerank_result.candidates[{i}]",
                f"expected RerankCandidate, got {type(c).__name__}",
            )
        object.__setattr__(self, "candidates", cands)


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
    """The matcher's output for one frame; the result contract's invariants are checked here."""

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
