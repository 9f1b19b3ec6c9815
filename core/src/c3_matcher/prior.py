"""The geometric prior of a rectified query: what the vehicle already knows.

With attitude and height, :class:`~c3_matcher.preprocess.FramePreprocessor` rectifies the query
to north-up nadir at the candidate's GSD, so the homography WORKING query px -> tile px of the
true tile is, up to the sensors' errors, a pure translation at scale 1. Two uses:

1. **Before RANSAC** (:meth:`GeometricPrior.consistent`): every putative match votes with its
   displacement ``d = tile - query`` for the translation; the dominant translation is the
   densest cell of a vote grid (3x3 neighbourhood sum, ``vote_cell_px``), refined by the median
   of its supporters; a match is kept when ``|d - t| <= base_tolerance_px + r * slope`` with
   ``r`` its distance from the query's nadir point (the rotation centre of the attitude error)
   and ``slope = tan(rotation_tolerance) + scale_tolerance`` (how far a heading error or a
   height error moves a point at radius ``r``).
2. **After RANSAC** (:meth:`GeometricPrior.verify`): the homography's local affine map at the
   nadir point must have a scale ``sqrt(det)`` within ``1 +- scale_tolerance``, a rotation within
   ``rotation_tolerance_deg``, an anisotropy (singular-value ratio - 1, i.e. shear and
   non-uniform stretch) within ``shear_tolerance``, and the query footprint mapped into the tile
   an area within ``(1 +- scale_tolerance)^2`` times its own, convex and not mirrored. A candidate
   that fails is refused on geometry whatever its inlier count.

Only built when the frame had attitude AND height AND the tile GSD is known (the prepared query
has ``nadir_working_px`` and ``working_gsd_m``); otherwise there is no prior and the pipeline
runs as before. The tolerance rationale is in docs/decisions.md ("The geometric prior").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.config import MatcherSettings, matcher_default

__all__ = [
    "GeometricPrior",
    "HomographyCheck",
    "PriorTolerances",
]


@dataclass(frozen=True, slots=True)
class PriorTolerances:
    """How far the true homography may be from a pure translation (see docs/decisions.md); the
    defaults are ``[matcher]``'s ``prior_*`` settings'."""

    rotation_deg: float = matcher_default("prior_rotation_tol_deg")
    scale: float = matcher_default("prior_scale_tol")
    shear: float = matcher_default("prior_shear_tol")
    base_px: float = matcher_default("prior_base_tol_px")
    vote_cell_px: float = 16.0

    @classmethod
    def from_settings(cls, matcher: MatcherSettings) -> PriorTolerances:
        """The tolerances ``[matcher]``'s ``prior_*`` settings give."""
        return cls(
            rotation_deg=matcher.prior_rotation_tol_deg,
            scale=matcher.prior_scale_tol,
            shear=matcher.prior_shear_tol,
            base_px=matcher.prior_base_tol_px,
        )


@dataclass(frozen=True, slots=True)
class HomographyCheck:
    """The verdict on one homography: its measured scale, rotation (deg), anisotropy, area
    ratio, and ``reason`` (empty when it passed)."""

    scale: float
    rotation_deg: float
    anisotropy: float
    area_ratio: float
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason


class GeometricPrior:
    """The prior of one rectified query: its nadir point (WORKING px) and footprint polygon."""

    def __init__(
        self,
        tolerances: PriorTolerances,
        centre_px: tuple[float, float],
        footprint_px: F64 | None = None,
    ) -> None:
        self.tol = tolerances
        self.centre = np.asarray(centre_px, dtype=np.float64)
        self.footprint = None if footprint_px is None else np.asarray(footprint_px, np.float64)
        self.slope = math.tan(math.radians(tolerances.rotation_deg)) + tolerances.scale

    def consistent(self, correspondences: NDArray[np.floating]) -> NDArray[np.bool_]:
        """Mask of the (M, 4) rows (x_q, y_q, x_t, y_t) consistent with the dominant
        translation (all False when fewer than 4 rows)."""
        m = correspondences.shape[0]
        if m < 4:
            return np.zeros(m, dtype=bool)
        q = correspondences[:, 0:2].astype(np.float64)
        d = correspondences[:, 2:4].astype(np.float64) - q
        cell = self.tol.vote_cell_px
        guess = (_densest_cell(np.floor(d / cell).astype(np.int64)) + 0.5) * cell
        radius = np.linalg.norm(q - self.centre, axis=1)
        tolerance = self.tol.base_px + radius * self.slope
        near = np.linalg.norm(d - guess, axis=1) <= tolerance + 1.5 * cell
        if not near.any():
            return np.zeros(m, dtype=bool)
        translation = np.median(d[near], axis=0)
        return np.asarray(np.linalg.norm(d - translation, axis=1) <= tolerance, dtype=bool)

    def verify(self, homography: F64) -> HomographyCheck:
        """Check ``homography`` (WORKING query px -> tile px) against the prior."""
        h = np.asarray(homography, dtype=np.float64)
        a = _jacobian(h, self.centre)
        det = float(np.linalg.det(a))
        if not math.isfinite(det) or det <= 0:
            return HomographyCheck(math.nan, math.nan, math.nan, math.nan, "mirrored or singular")
        scale = math.sqrt(det)
        rotation = math.degrees(math.atan2(a[1, 0] - a[0, 1], a[0, 0] + a[1, 1]))
        s = np.linalg.svd(a, compute_uv=False)
        anisotropy = float(s[0] / s[1]) - 1.0
        area_ratio = _area_ratio(h, self.footprint) if self.footprint is not None else scale**2
        tol = self.tol
        reason = ""
        if abs(math.log(scale)) > math.log1p(tol.scale):
            reason = f"scale {scale:.3f} outside 1 +- {tol.scale}"
        elif abs(rotation) > tol.rotation_deg:
            reason = f"rotation {rotation:.1f} deg beyond {tol.rotation_deg} deg"
        elif anisotropy > tol.shear:
            reason = f"shear/anisotropy {anisotropy:.3f} beyond {tol.shear}"
        elif not math.isfinite(area_ratio) or not (
            (1 + tol.scale) ** -2 <= area_ratio <= (1 + tol.scale) ** 2
        ):
            reason = f"footprint area ratio {area_ratio:.3f} outside (1 +- {tol.scale})^2"
        return HomographyCheck(scale, rotation, anisotropy, area_ratio, reason)

    def similarity_ransac(
        self,
        correspondences: NDArray[np.floating],
        threshold_px: float,
        *,
        max_iters: int = 10_000,
        confidence: float = 0.9999,
    ) -> tuple[F64, NDArray[np.bool_]] | None:
        """The model the prior implies, fitted robustly: a 4-DOF similarity (rotation, uniform
        scale, translation; OpenCV RANSAC + Levenberg-Marquardt refinement, deterministic) of
        the (M, 4) rows, as a 3x3 homography, and its inlier mask; None with fewer than 4 rows
        or no fit. Used when a free homography fails :meth:`verify`: with few or clustered
        inliers (a shoreline, one field edge) its 4 extra degrees of freedom fit noise and
        extrapolate a false scale or shear to the nadir point, while a rectified query and its
        true tile differ by a similarity (exactly so with exact attitude and height)."""
        m = correspondences.shape[0]
        if m < 4:
            return None
        src = np.ascontiguousarray(correspondences[:, 0:2], dtype=np.float64)
        dst = np.ascontiguousarray(correspondences[:, 2:4], dtype=np.float64)
        try:
            found, mask = cv2.estimateAffinePartial2D(
                src,
                dst,
                method=cv2.RANSAC,
                ransacReprojThreshold=threshold_px,
                maxIters=max_iters,
                confidence=confidence,
                refineIters=10,
            )
        except cv2.error:
            return None
        if found is None or mask is None or not np.isfinite(found).all():
            return None
        homography = np.vstack([np.asarray(found, dtype=np.float64), [0.0, 0.0, 1.0]])
        return homography, mask.reshape(-1).astype(bool)


DENSE_VOTE_CELLS = 1 << 20
"""Votes that fit a grid of this many cells are box-filtered on it whole; a wider spread is
scored sparsely. At its peak the dense vote holds the counts (int64, 8 MB at 2^20 cells) and
their float32 copy (4 MB), then that copy and its box sum (4 + 4 MB): 12 MB at most."""


def _densest_cell(keys: NDArray[np.int64], dense_cells: int = DENSE_VOTE_CELLS) -> F64:
    """The (x, y) vote cell whose 3x3 neighbourhood holds the most of ``keys`` (N, 2), the first
    in row-major order on a tie. Votes that fit a grid of ``dense_cells`` are box-filtered on it
    (the fast common case); votes spread wider (a large height, a mistyped tile GSD) are scored
    only at the cells next to a vote, so memory and time grow with the votes, not the spread."""
    lo = keys.min(axis=0) - 1  # a free cell each side: x +- 1 never leaves its row
    width, rows = (int(n) for n in keys.max(axis=0) - lo + 2)
    codes = (keys[:, 1] - lo[1]) * width + (keys[:, 0] - lo[0])  # ascending = row-major order
    if width * rows <= dense_cells:
        # float32 sums are exact: a cell's 3x3 sum counts at most the matches, far below 2^24
        grid = np.bincount(codes, minlength=width * rows).astype(np.float32).reshape(rows, width)
        summed = cv2.boxFilter(grid, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        best = int(np.argmax(summed))  # first max: stable
    else:
        voted, counts = np.unique(codes, return_counts=True)
        steps = (np.arange(-1, 2)[:, None] * width + np.arange(-1, 2)[None, :]).ravel()
        scored = np.unique((voted[:, None] + steps[None, :]).ravel())
        sums = np.zeros(scored.size, dtype=np.int64)
        for step in steps:
            at = np.searchsorted(voted, scored + step).clip(max=voted.size - 1)
            sums += np.where(voted[at] == scored + step, counts[at], 0)
        best = int(scored[int(np.argmax(sums))])  # first max: stable
    row, col = divmod(best, width)
    return np.array([col + lo[0], row + lo[1]], dtype=np.float64)


def _jacobian(h: F64, p: F64) -> F64:
    """The 2x2 derivative of the homography ``h`` at point ``p``."""
    x, y = float(p[0]), float(p[1])
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    u = h[0, 0] * x + h[0, 1] * y + h[0, 2]
    v = h[1, 0] * x + h[1, 1] * y + h[1, 2]
    if w == 0:
        return np.full((2, 2), np.nan)
    return np.array(
        [
            [(h[0, 0] * w - u * h[2, 0]) / w**2, (h[0, 1] * w - u * h[2, 1]) / w**2],
            [(h[1, 0] * w - v * h[2, 0]) / w**2, (h[1, 1] * w - v * h[2, 1]) / w**2],
        ]
    )


def _area_ratio(h: F64, polygon: F64) -> float:
    """Area of ``polygon`` mapped by ``h`` over its own; NaN when the image is not a convex,
    same-orientation polygon in front of the camera (a degenerate homography)."""
    pts = np.hstack([polygon, np.ones((polygon.shape[0], 1))]) @ h.T
    if (pts[:, 2] <= 0).any():
        return math.nan
    mapped = pts[:, :2] / pts[:, 2:3]
    before = _signed_area(polygon)
    after = _signed_area(mapped)
    if before == 0 or after * before <= 0:
        return math.nan
    if not cv2.isContourConvex(mapped.astype(np.float32).reshape(-1, 1, 2)):
        return math.nan
    return abs(after / before)


def _signed_area(p: F64) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
