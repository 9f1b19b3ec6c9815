"""``OpenCvRansacFilter``: the one RANSAC + median-residual helper shared by C3, C3.5, C4.

Homography (the right model for nadir-ish views of terrain) estimated with OpenCV's
USAC MAGSAC++, seeded so that the same correspondences give the same inliers bit for bit.

Optional final refit (``refit_px`` > 0, ``refit``): the inliers within ``refit_px`` of the
homography are kept and the homography is re-fitted to them by least squares, unless that would
leave fewer than ``refit_floor`` inliers (the pipeline's ``min_inliers_threshold``, so a refit
never drops a candidate below it). It narrows the inliers handed downstream to the precise ones;
docs/precision.md measures it per strategy.

:func:`spread_ratio` measures how widely inliers spread: points on or near one line fix a
homography only along that line, its other parameters fitted to noise, so a tiny residual there
promises nothing about the rest of the frame; a frame with no geometric prior to pin them is
refused below :data:`MIN_SPREAD_RATIO` (``stages.verify.SpreadCheck``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.dto import RansacResult

if TYPE_CHECKING:
    from c3_matcher.config import MatcherSettings

__all__ = [
    "MIN_SPREAD_RATIO",
    "OpenCvRansacFilter",
    "homography_residuals",
    "refit",
    "spread_ratio",
]

MIN_CORRESPONDENCES = 4

MIN_SPREAD_RATIO = 0.2
"""The least :func:`spread_ratio` a homography's inliers must have on both sides (query and
tile) where no geometric prior checks it. A homography has 8 parameters; its two perspective
terms (and the shear across a line) are pinned only by how far the points spread across their
longest direction. Points in a band whose width is under a fifth of its length (a road, a
field edge, texture along one line) leave them to noise: with a pure shift as the truth such a
fit can move the far corners of the frame by tens of pixels while its residual stays below a
pixel (it may as well come out right: nothing tells which). The ratio is unitless and
unchanged by a similarity on either side, so the rule does not depend on frame size, ground
sample distance, rotation or strategy, only on the shape of the point cloud.

Measured: the true tile's inliers on every frame of the shipped flights reach at least 0.36
(XFeat) to 0.46 (SIFT, ALIKED) and every inlier set of 60 or more at least 0.30, while inliers
confined to a 20 to 32 px band of a 400 x 300 query give 0.07 to 0.12 and points on one line
0 to 0.003: 0.2 leaves a margin of 1.5 or more on either side."""


def homography_residuals(
    homography: NDArray[np.float64], correspondences: NDArray[np.floating]
) -> NDArray[np.float64]:
    """Reprojection error (px, second image) of (x0, y0, x1, y1) rows under ``homography``."""
    src = correspondences[:, 0:2].astype(np.float64)
    dst = correspondences[:, 2:4].astype(np.float64)
    projected = cv2.perspectiveTransform(src.reshape(-1, 1, 2), homography).reshape(-1, 2)
    return np.asarray(np.linalg.norm(projected - dst, axis=1), dtype=np.float64)


class OpenCvRansacFilter:
    """RANSAC homography filter over float32 (M, 4) = (x_query, y_query, x_tile, y_tile) rows.

    Threshold and residuals are in tile pixels. Fewer than 4 correspondences, degenerate input or a
    failed estimate give zero inliers (no exception). ``confidence`` and ``max_iters`` follow
    OpenCV's USAC parameters; ``seed`` fixes its random generator (determinism).
    """

    def __init__(
        self,
        *,
        confidence: float = 0.9999,
        max_iters: int = 10_000,
        seed: int = 0,
        refine: bool = True,
        refit_px: float = 0.0,
        refit_floor: int = MIN_CORRESPONDENCES,
    ) -> None:
        v.require(0 < confidence < 1, "ransac.confidence", f"must be in (0, 1), got {confidence}")
        v.require(max_iters > 0, "ransac.max_iters", f"must be > 0, got {max_iters}")
        v.require(
            math.isfinite(refit_px) and refit_px >= 0,
            "ransac.refit_px",
            f"must be finite and >= 0, got {refit_px}",
        )
        self.refit_px = float(refit_px)
        self.refit_floor = int(refit_floor)
        self._confidence, self._max_iters, self._seed = confidence, max_iters, seed
        self._refine = refine

    @classmethod
    def from_settings(cls, matcher: MatcherSettings) -> OpenCvRansacFilter:
        """The filter ``[matcher]`` asks for, resolved for its strategy (``refit_threshold_px``
        set: unset means none): its seed, and a refit over the inliers within the refit
        threshold kept only while at least ``min_inliers_threshold`` remain."""
        return cls(
            seed=matcher.ransac_seed,
            refit_px=matcher.refit_threshold_px or 0.0,
            refit_floor=matcher.min_inliers_threshold,
        )

    def _usac_params(self, threshold: float) -> cv2.UsacParams:
        """OpenCV's USAC parameters for one call: built per call, so no call sees another's
        threshold (the filter is shared with the stages after the matcher, on other threads)."""
        params = cv2.UsacParams()
        params.threshold = threshold
        params.confidence = self._confidence
        params.maxIterations = self._max_iters
        params.randomGeneratorState = self._seed
        params.sampler = cv2.SAMPLING_UNIFORM
        params.score = cv2.SCORE_METHOD_MAGSAC
        params.loMethod = cv2.LOCAL_OPTIM_SIGMA
        params.loIterations = 10
        params.loSampleSize = 50
        params.final_polisher = cv2.MAGSAC if self._refine else cv2.NONE_POLISHER
        params.final_polisher_iterations = 10 if self._refine else 0
        params.isParallel = False
        return params

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        corr = v.array(correspondences, "correspondences", dtype=np.float32, shape=(None, 4))
        threshold = v.finite_float(threshold_px, "threshold_px")
        v.require(threshold > 0, "threshold_px", f"must be > 0, got {threshold}")
        m = corr.shape[0]
        if m < MIN_CORRESPONDENCES:
            return _empty(m)
        src = np.ascontiguousarray(corr[:, 0:2], dtype=np.float64)
        dst = np.ascontiguousarray(corr[:, 2:4], dtype=np.float64)
        try:
            found, mask = cv2.findHomography(src, dst, self._usac_params(threshold))
        except cv2.error:
            return _empty(m)
        if found is None or mask is None or not np.isfinite(found).all():
            return _empty(m)
        homography: NDArray[np.float64] = np.asarray(found, dtype=np.float64)
        inlier_mask = mask.reshape(-1).astype(bool)
        if int(inlier_mask.sum()) < MIN_CORRESPONDENCES:
            return _empty(m)
        inliers = np.ascontiguousarray(corr[inlier_mask])
        residuals = homography_residuals(homography, inliers)
        result = RansacResult(
            inlier_correspondences=inliers,
            ransac_outlier_count=int(m - inliers.shape[0]),
            per_candidate_residual_px=float(np.median(residuals)),
            homography=homography,
            inlier_mask=inlier_mask,
        )
        return refit(result, self.refit_px, floor=self.refit_floor)


def spread_ratio(points: NDArray[np.floating]) -> float:
    """How wide against how long the (N, 2) ``points`` lie: the smaller singular value of their
    centred coordinates over the larger, in [0, 1]. 0 for points on one line (or one point),
    1 for a cloud spread evenly in every direction; a w x l rectangle filled evenly gives w / l.
    Fewer than two points give 0."""
    coords = np.asarray(points, dtype=np.float64)
    v.require(
        coords.ndim == 2 and coords.shape[1] == 2, "points", f"expected (N, 2), got {coords.shape}"
    )
    if coords.shape[0] < 2:
        return 0.0
    singular = np.linalg.svd(coords - coords.mean(axis=0), compute_uv=False)
    if not singular[0] > 0:
        return 0.0
    return float(singular[1] / singular[0])


def refit(
    result: RansacResult, refit_px: float, *, floor: int = MIN_CORRESPONDENCES
) -> RansacResult:
    """``result`` with only the inliers within ``refit_px`` (px, second image) of its homography
    and the homography re-fitted to them (least squares, deterministic). Returned unchanged for
    ``refit_px`` <= 0, without a homography, or where fewer than ``floor`` (at least 4) inliers
    would remain, so a refit never takes a candidate below the caller's inlier threshold. The
    inliers kept are a subset of ``result``'s, in their order; the mask stays over the filter's
    input."""
    inliers = result.inlier_correspondences
    if refit_px <= 0 or result.homography is None:
        return result
    keep = homography_residuals(result.homography, inliers) <= refit_px
    if int(keep.sum()) < max(floor, MIN_CORRESPONDENCES):
        return result
    kept = np.ascontiguousarray(inliers[keep])
    src = np.ascontiguousarray(kept[:, 0:2], dtype=np.float64)
    dst = np.ascontiguousarray(kept[:, 2:4], dtype=np.float64)
    found, _ = cv2.findHomography(src, dst, 0)
    if found is None or not np.isfinite(found).all():
        return result
    homography: NDArray[np.float64] = np.asarray(found, dtype=np.float64)
    mask = result.inlier_mask.copy()
    mask[np.flatnonzero(result.inlier_mask)[~keep]] = False
    return RansacResult(
        inlier_correspondences=kept,
        ransac_outlier_count=int(mask.shape[0] - kept.shape[0]),
        per_candidate_residual_px=float(np.median(homography_residuals(homography, kept))),
        homography=homography,
        inlier_mask=mask,
    )


def _empty(m: int) -> RansacResult:
    return RansacResult(
        inlier_correspondences=np.zeros((0, 4), dtype=np.float32),
        ransac_outlier_count=m,
        per_candidate_residual_px=0.0,
        homography=None,
        inlier_mask=np.zeros(m, dtype=bool),
    )
