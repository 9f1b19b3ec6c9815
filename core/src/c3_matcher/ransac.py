"""``OpenCvRansacFilter`` (AZ-282): the one RANSAC + median-residual helper shared by C3, C3.5, C4.

Homography (the right model for nadir-ish views of terrain, DECISIONS 13) estimated with OpenCV's
USAC MAGSAC++, seeded so that the same correspondences give the same inliers bit for bit.

``refit`` is an optional final step on a filter's result (``REFIT_MODES``): the inliers handed
downstream re-selected and the homography re-fitted on them (docs/precision.md measures it).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher import _validate as v
from c3_matcher.dto import RansacResult

__all__ = ["REFIT_MODES", "OpenCvRansacFilter", "homography_residuals", "refit"]

MIN_CORRESPONDENCES = 4
REFIT_MODES = ("none", "tight")
"""Final refit of a RANSAC result's inliers (``refit``): ``none`` keeps the result as it is;
``tight`` keeps the inliers within ``factor`` x the RANSAC threshold of the homography and
re-fits the homography to them by least squares, unless fewer than ``floor`` would remain."""
DEFAULT_TIGHT_FACTOR = 0.5


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
    OpenCV's USAC parameters; ``seed`` fixes its random generator (determinism, AC-10).
    """

    def __init__(
        self,
        *,
        confidence: float = 0.9999,
        max_iters: int = 10_000,
        seed: int = 0,
        refine: bool = True,
    ) -> None:
        v.require(0 < confidence < 1, "ransac.confidence", f"must be in (0, 1), got {confidence}")
        v.require(max_iters > 0, "ransac.max_iters", f"must be > 0, got {max_iters}")
        self._params = cv2.UsacParams()
        self._params.confidence = confidence
        self._params.maxIterations = max_iters
        self._params.randomGeneratorState = seed
        self._params.sampler = cv2.SAMPLING_UNIFORM
        self._params.score = cv2.SCORE_METHOD_MAGSAC
        self._params.loMethod = cv2.LOCAL_OPTIM_SIGMA
        self._params.loIterations = 10
        self._params.loSampleSize = 50
        self._params.final_polisher = cv2.MAGSAC if refine else cv2.NONE_POLISHER
        self._params.final_polisher_iterations = 10 if refine else 0
        self._params.isParallel = False

    def filter(self, correspondences: NDArray[np.float32], threshold_px: float) -> RansacResult:
        corr = v.array(correspondences, "correspondences", dtype=np.float32, shape=(None, 4))
        threshold = v.finite_float(threshold_px, "threshold_px")
        v.require(threshold > 0, "threshold_px", f"must be > 0, got {threshold}")
        m = corr.shape[0]
        if m < MIN_CORRESPONDENCES:
            return _empty(m)
        self._params.threshold = threshold
        src = np.ascontiguousarray(corr[:, 0:2], dtype=np.float64)
        dst = np.ascontiguousarray(corr[:, 2:4], dtype=np.float64)
        try:
            found, mask = cv2.findHomography(src, dst, self._params)
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
        return RansacResult(
            inlier_correspondences=inliers,
            ransac_outlier_count=int(m - inliers.shape[0]),
            per_candidate_residual_px=float(np.median(residuals)),
            homography=homography,
            inlier_mask=inlier_mask,
        )


def refit(
    result: RansacResult,
    mode: str,
    threshold_px: float,
    *,
    factor: float = DEFAULT_TIGHT_FACTOR,
    floor: int = MIN_CORRESPONDENCES,
) -> RansacResult:
    """``result`` after the final refit ``mode`` (``REFIT_MODES``) at the filter's
    ``threshold_px`` (tile px): for ``tight``, the inliers within ``factor * threshold_px`` of
    the homography, and the homography re-fitted to them (least squares, deterministic). The
    result is returned unchanged for ``none``, without a homography, or where fewer than
    ``floor`` (at least 4) inliers would remain, so a refit never takes a candidate below the
    caller's inlier threshold. The inliers kept are a subset of ``result``'s, in their order;
    the mask stays over the filter's input."""
    if mode not in REFIT_MODES:
        raise ValueError(f"refit mode must be one of {REFIT_MODES}, got {mode!r}")
    inliers = result.inlier_correspondences
    if mode == "none" or result.homography is None:
        return result
    keep = homography_residuals(result.homography, inliers) <= factor * threshold_px
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
