"""An image ready for the extractor and its coordinate maps.

:class:`InputRule` is an engine's input size rule; :class:`PreparedImage` carries the engine
image, its valid mask and every map back to the pixels RANSAC and C5 use: ENGINE -> WORKING,
WORKING -> ORIGINAL, a quarter turn of the query (rotation search), and the correspondences of a
match in WORKING px. How a query is rendered is in :mod:`c3_matcher.preprocess`.

Coordinate frames (pixels 0-based, origin at the centre of the top-left pixel, points (x, y)):

- ORIGINAL: the raw, distorted frame as captured.
- UNDISTORTED: ``K @ (x/z, y/z, 1)`` of the ray, with the calibration's own K.
- WORKING: for the query, the undistorted, rectified (north-up nadir) frame at
  the GSD-scaled resolution, before the engine resize; RANSAC runs here. For a tile, the tile's
  full-resolution pixels.
- ENGINE: the pixels of :attr:`PreparedImage.image`, the extractor's input.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from c3_matcher import camera as cam
from c3_matcher.arrays import F64
from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features, RawMatches

__all__ = [
    "MAX_UPSCALE",
    "InputRule",
    "PreparedImage",
    "check_pairs",
    "correspondences",
    "engine_to_working",
    "rotation_from_turned",
]


MAX_UPSCALE = 4
"""The largest ``InputRule.upscale``: the engine's work grows with its square."""


@dataclass(frozen=True)
class InputRule:
    """An engine's input rule: downscale so the long side <= ``max_long_side`` px (never
    upscale); make the final width and height multiples of ``multiple`` (padding is masked).
    ``upscale``: the extractor is run on the prepared image enlarged by this whole factor
    (``run_extractor``), its keypoints given back in the prepared image's px; for a model whose
    descriptors come from a coarse map, so that small images still give it a fine one."""

    max_long_side: int
    multiple: int
    upscale: int = 1

    def __post_init__(self) -> None:
        for name in ("max_long_side", "multiple", "upscale"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise InvalidInputError(f"input_rule.{name}", f"expected an int > 0, got {value!r}")
        if self.upscale > MAX_UPSCALE:
            raise InvalidInputError(
                "input_rule.upscale", f"at most {MAX_UPSCALE}, got {self.upscale}"
            )
        if self.max_long_side < self.multiple:
            raise InvalidInputError(
                "input_rule.max_long_side", f"{self.max_long_side} < multiple {self.multiple}"
            )

    def content_size(self, width: int, height: int) -> tuple[int, int]:
        """(w, h) px of a width x height image after the downscale (before pad/crop)."""
        r = min(1.0, self.max_long_side / max(width, height))
        return max(1, round(width * r)), max(1, round(height * r))

    def final_size(self, width: int, height: int) -> tuple[int, int]:
        """(w, h) px of the engine input for a width x height image: each side of the content
        size rounded up to ``multiple`` (padding), or down when up would exceed the limit."""

        def snap(n: int) -> int:
            up = -(-n // self.multiple) * self.multiple
            if up <= self.max_long_side:
                return up
            return max(self.multiple, (n // self.multiple) * self.multiple)

        cw, ch = self.content_size(width, height)
        return snap(cw), snap(ch)


def engine_to_working(working_size: tuple[int, int], content_size: tuple[int, int]) -> F64:
    """3x3 ENGINE -> WORKING px map of an engine image whose content (before pad or crop) is
    ``content_size`` (w, h) px of a ``working_size`` (w, h) px image: ``x_w = (x_e + 0.5) * sx -
    0.5``, the area-aligned convention of ``cv2.resize``."""
    sx = working_size[0] / content_size[0]
    sy = working_size[1] / content_size[1]
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PreparedImage:
    """An image ready for the extractor, and the maps back to the pixels RANSAC and C5 use.

    ``image`` uint8 (H, W, 3) RGB, H and W multiples of the rule's ``multiple``; ``valid`` bool
    (H, W), True where keypoints may be kept (not padding, warp border or nodata, eroded).
    ``working_from_engine`` 3x3 (ENGINE -> WORKING px): a scale and shift, a turn (rotation
    search) or a homography (a query re-rendered through a first match, the refine pass);
    ``working_size`` (w, h) of the
    working image; for a query, ``working_from_undistorted`` is the 3x3 homography H_w
    (UNDISTORTED -> WORKING px) and ``calibration`` the frame's calibration (both None for a
    tile). ``working_gsd_m`` is the working image's ground sample distance at nadir (m/px) when
    known; ``nadir_working_px`` the working pixel straight below the camera (rectified queries).
    """

    image: NDArray[np.uint8]
    valid: NDArray[np.bool_]
    working_from_engine: F64
    working_size: tuple[int, int]
    working_from_undistorted: F64 | None = None
    calibration: CameraCalibration | None = None
    working_gsd_m: float | None = None
    nadir_working_px: tuple[float, float] | None = None
    _undistorted_from_working: F64 | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.working_from_undistorted is not None:
            inv = np.linalg.inv(self.working_from_undistorted)
            object.__setattr__(self, "_undistorted_from_working", inv)

    @property
    def engine_size(self) -> tuple[int, int]:
        """(w, h) px of :attr:`image`."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    def to_working(self, pts: ArrayLike) -> F64:
        """(N, 2) ENGINE px -> (N, 2) WORKING px."""
        return cam.apply_homography(self.working_from_engine, pts)

    def to_engine(self, pts: ArrayLike) -> F64:
        """(N, 2) WORKING px -> (N, 2) ENGINE px (inverse of :meth:`to_working`)."""
        return cam.apply_homography(np.linalg.inv(self.working_from_engine), pts)

    def working_to_original(self, pts: ArrayLike) -> F64:
        """(N, 2) WORKING px -> (N, 2) ORIGINAL (distorted) frame px; the identity for tiles.

        Inverts the rectification homography and re-applies the exact lens model. A working
        point whose ray lies behind the real camera maps to NaN.
        """
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if self._undistorted_from_working is None or self.calibration is None:
            return p.copy()
        hinv = self._undistorted_from_working
        q = p @ hinv[:, :2].T + hinv[:, 2]
        in_front = q[:, 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            und = q[:, :2] / q[:, 2:3]
        out = np.full_like(p, np.nan)
        if np.any(in_front):
            out[in_front] = cam.distort_points(und[in_front], self.calibration)
        return out

    def original_to_working(self, pts: ArrayLike) -> F64:
        """(N, 2) ORIGINAL (distorted) frame px -> (N, 2) WORKING px; the identity for tiles."""
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if self.working_from_undistorted is None or self.calibration is None:
            return p.copy()
        und = cam.undistort_points(p, self.calibration)
        return cam.apply_homography(self.working_from_undistorted, und)

    def engine_to_original(self, pts: ArrayLike) -> F64:
        """(N, 2) ENGINE px -> (N, 2) ORIGINAL px (:meth:`to_working` then
        :meth:`working_to_original`)."""
        return self.working_to_original(self.to_working(pts))

    def turned(self, rotation_deg: int) -> PreparedImage:
        """This image turned ``rotation_deg`` (a multiple of 90) counter-clockwise (pixels and
        valid mask, ``np.rot90``), with the turn composed into ``working_from_engine`` so its
        ENGINE px still map to the WORKING px of the unturned image; ``self`` for 0."""
        if rotation_deg == 0:
            return self
        k = rotation_deg // 90
        w, h = self.engine_size
        return dataclasses.replace(
            self,
            image=np.ascontiguousarray(np.rot90(self.image, k)),
            valid=np.ascontiguousarray(np.rot90(self.valid, k)),
            working_from_engine=self.working_from_engine @ rotation_from_turned(rotation_deg, w, h),
        )

    def from_undistorted(self, model: F64 | None) -> F64 | None:
        """A 3x3 ``model`` from this query's WORKING px (to a tile's px) composed with the
        rectification: from UNDISTORTED query px, scaled so its [2, 2] is 1; None without a
        model or without the rectification (an unrectified query's WORKING px are ORIGINAL)."""
        if model is None or self.working_from_undistorted is None:
            return None
        composed = model @ self.working_from_undistorted
        return np.asarray(composed / composed[2, 2], dtype=np.float64)

    def in_original_px(self, rows: NDArray[np.float32]) -> NDArray[np.float32]:
        """(M, 4) correspondence rows (x_query, y_query, x_tile, y_tile) with the query point
        moved from WORKING to ORIGINAL frame px (:meth:`working_to_original`), float32."""
        original = self.working_to_original(rows[:, 0:2].astype(np.float64))
        return np.hstack([original, rows[:, 2:4]]).astype(np.float32)


def rotation_from_turned(rotation_deg: int, width: int, height: int) -> F64:
    """3x3 map of ENGINE px of an image turned ``rotation_deg`` (a multiple of 90)
    counter-clockwise with ``np.rot90`` back to ENGINE px of the ``width`` x ``height`` image
    (pixel centres at integers)."""
    if rotation_deg % 90:
        raise ValueError(f"rotation_deg must be a multiple of 90, got {rotation_deg}")
    out = np.eye(3)
    w, h = width, height
    for _ in range((rotation_deg // 90) % 4):
        # one np.rot90 of a w-wide image: turned (x', y') reads unturned (w - 1 - y', x')
        out = out @ np.array([[0.0, -1.0, w - 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        w, h = h, w
    return out


def correspondences(
    query_image: PreparedImage,
    query: Features,
    tile_image: PreparedImage,
    tile: Features,
    raw: RawMatches,
) -> NDArray[np.float32]:
    """(M, 4) float32 rows (x_query, y_query, x_tile, y_tile) of ``raw`` matches in WORKING px
    (rectified query, full-resolution tile); (0, 4) without a match; ``ValueError`` where the
    pairs are no pairs of these keypoints (:func:`check_pairs`)."""
    if len(raw) == 0:
        return np.zeros((0, 4), dtype=np.float32)
    check_pairs(raw, len(query), len(tile))
    q = query_image.to_working(query.keypoints[raw.matches[:, 0]].astype(np.float64))
    t = tile_image.to_working(tile.keypoints[raw.matches[:, 1]].astype(np.float64))
    return np.hstack([q, t]).astype(np.float32)


def check_pairs(raw: RawMatches, query_count: int, tile_count: int) -> None:
    """``ValueError`` naming the index when a match of a query of ``query_count`` keypoints with
    a tile of ``tile_count`` points at no keypoint (a backend's -1 for "unmatched" would
    otherwise pair the last keypoint) or pairs one query keypoint, or one tile keypoint, more
    than once (each pair would count as an inlier of its own): the one check of a backend's
    pairs, in flight and in the start-up probe."""
    if len(raw) == 0:
        return
    for column, (side, count) in enumerate((("query", query_count), ("tile", tile_count))):
        index = raw.matches[:, column]
        outside = index[(index < 0) | (index >= count)]
        if outside.size:
            raise ValueError(
                f"the matcher's output pairs {side} keypoint {int(outside[0])}, but the {side} "
                f"has {count} keypoints (indices 0..{count - 1})"
            )
    for column, side in enumerate(("query", "tile")):
        uses = np.bincount(raw.matches[:, column], minlength=1)
        if uses.max() > 1:
            twice = int(np.argmax(uses))
            raise ValueError(
                f"the matcher's output pairs {side} keypoint {twice} {int(uses[twice])} times "
                f"(each {side} keypoint may be in one pair at most)"
            )
