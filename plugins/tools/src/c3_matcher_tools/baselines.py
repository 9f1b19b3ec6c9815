"""The classical reference: OpenCV SIFT + ratio-test matching, run through the SAME pipeline
(preprocessing, MAGSAC RANSAC, ranking) as the learned strategies, so benchmarks and evaluations
compare like with like."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from c3_matcher.config import C3Settings
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.strategy import DEFAULT_MAX_KEYPOINTS, backend_strategy_factory

__all__ = ["SIFT_LABEL", "SiftBackend", "SiftOptions", "create", "distinct_strongest"]

SIFT_LABEL = "sift_magsac"
#: the first pass describes this many of an image's strongest keypoints per keypoint of the
#: budget: room for the budget's locations, their other orientation peaks (a fifth to a half more
#: on the shipped imagery, budgets 512 to 2048) and those outside the valid mask, so that the
#: second pass, every keypoint, is rare
FIRST_PASS_FACTOR = 2


class SiftBackend:
    """KeypointBudgetBackend: SIFT keypoints (OpenCV) inside the valid mask, one per image
    location, at most ``max_keypoints`` per image (see :func:`distinct_strongest`), Lowe ratio
    test + mutual check on L2 distances. Deterministic (OpenCV SIFT and brute force are, and the
    keypoints kept are chosen in a fixed order). It names no extractor engine: its tiles are
    extracted."""

    label = SIFT_LABEL
    extract_phase = "sift_extract"
    match_phase = "sift_match"

    def __init__(
        self, rule: InputRule, max_keypoints: int = DEFAULT_MAX_KEYPOINTS, ratio: float = 0.85
    ) -> None:
        self.input_rule = rule
        self.max_keypoints = max_keypoints
        self._first_pass = FIRST_PASS_FACTOR * max_keypoints
        self._passes = (cv2.SIFT.create(nfeatures=self._first_pass), cv2.SIFT.create())
        self._matcher = cv2.BFMatcher(cv2.NORM_L2)
        self._ratio = ratio

    def extract(self, image: PreparedImage) -> Features:
        """The keypoints :func:`distinct_strongest` keeps of every SIFT keypoint inside the valid
        mask, described: describing every keypoint first takes up to 1.8x the time on dense
        imagery and would skew the timings this reference is compared by. OpenCV keeps an
        image's ``n`` strongest keypoints (and any tied with the n-th) before it applies a mask
        and describes them, so the first pass, unmasked, holds every keypoint at least as strong
        as its weakest. When it holds the whole budget of distinct locations, or fewer than
        ``n`` keypoints (the image has no more), its choice is the one every keypoint gives, and
        its descriptors are too (the same pyramid); otherwise a second pass describes every
        keypoint."""
        grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
        unmasked = np.zeros((0, 0), np.uint8)  # OpenCV masks after choosing: see _in_mask
        for sift in self._passes:
            keypoints, descriptors = sift.detectAndCompute(grey, unmasked)
            n = len(keypoints)
            pts = np.array([k.pt for k in keypoints], np.float32).reshape(n, 2)
            scores = np.array([k.response for k in keypoints], np.float32).reshape(n)
            angles = np.array([k.angle for k in keypoints], np.float32).reshape(n)
            inside = np.flatnonzero(_in_mask(pts, image.valid))
            keep = inside[
                distinct_strongest(pts[inside], scores[inside], angles[inside], self.max_keypoints)
            ]
            if n < self._first_pass or len(keep) == self.max_keypoints:
                break
        desc = np.zeros((0, 128), np.float32) if descriptors is None else descriptors
        return Features(pts[keep], desc[keep].astype(np.float32), scores[keep], image.engine_size)

    def match(self, query: Features, tile: Features) -> RawMatches:
        if len(query) < 2 or len(tile) < 2:
            return RawMatches(np.zeros((0, 2), np.int64), np.zeros(0, np.float32))
        forward = self._matcher.knnMatch(query.descriptors, tile.descriptors, k=2)
        backward = {
            m.queryIdx: m.trainIdx for m in self._matcher.match(tile.descriptors, query.descriptors)
        }
        rows, scores = [], []
        for pair in forward:
            if len(pair) < 2:
                continue
            best, second = pair
            if (
                best.distance < self._ratio * second.distance
                and backward.get(best.trainIdx) == best.queryIdx
            ):
                rows.append((best.queryIdx, best.trainIdx))
                scores.append(1.0 - best.distance / max(second.distance, 1e-9))
        return RawMatches(np.array(rows, np.int64).reshape(-1, 2), np.array(scores, np.float32))

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": "opencv", "engines": {"sift": cv2.__version__}}


def distinct_strongest(
    points: NDArray[np.float32],
    responses: NDArray[np.float32],
    angles: NDArray[np.float32],
    budget: int,
) -> NDArray[np.intp]:
    """Indices of the keypoints to keep: one per (x, y), the strongest response there, then the
    ``budget`` strongest of those, strongest first. OpenCV SIFT gives a location one keypoint
    per orientation peak (two or three at many corners, the same point and response, different
    descriptors); kept, one ground point becomes several matches, each an inlier, and a frame's
    inlier count passes the acceptance threshold on repeated evidence. Keeping one per location
    before the budget makes every inlier a distinct point, as every learned strategy's are, and
    the budget count distinct points. Equal responses order by x, y, then angle (at one location,
    the smallest angle is kept), so the same keypoints give the same choice whatever order
    OpenCV listed them in."""
    order = np.lexsort((angles, points[:, 1], points[:, 0], -responses))
    _, first = np.unique(points[order], axis=0, return_index=True)
    return order[np.sort(first)][:budget]


def _in_mask(points: NDArray[np.float32], valid: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Whether each keypoint lies in ``valid`` by OpenCV's rule for a detection mask (the pixel
    at ``(int)(x + 0.5f), (int)(y + 0.5f)``), so that masking after detection keeps the
    keypoints that passing the mask to OpenCV keeps."""
    half = np.float32(0.5)
    height, width = valid.shape
    cols = np.clip((points[:, 0] + half).astype(np.intp), 0, width - 1)
    rows = np.clip((points[:, 1] + half).astype(np.intp), 0, height - 1)
    return valid[rows, cols]


class SiftOptions(BaseModel):
    """The baseline takes no options of its own; it declares its keypoint budget, so that
    ``c3-matcher config`` checks the settings the budget makes unreachable as start-up does,
    and its pair matcher (``keypoint_budget.PairMatcherOptions``), so that ``[lightglue]``
    values set for it are said unread: it declares no engines to tell it by."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    def keypoint_budget(self, matcher_max_keypoints: int | None) -> int:
        """``[matcher] max_keypoints``, else the LightGlue strategies' default keypoints
        (:data:`~c3_matcher.strategy.config.DEFAULT_MAX_KEYPOINTS`)."""
        return matcher_max_keypoints or DEFAULT_MAX_KEYPOINTS

    def matches_with_lightglue(self) -> bool:
        """Never: it matches by the ratio test and a mutual check (:meth:`SiftBackend.match`)."""
        return False


def _sift_backend(config: C3Settings, options: SiftOptions) -> SiftBackend:
    """Long side from ``[matcher]``, the keypoint budget :meth:`SiftOptions.keypoint_budget`."""
    budget = options.keypoint_budget(config.matcher.max_keypoints)
    return SiftBackend(InputRule(config.matcher.max_long_side, 16), budget)


#: strategy factory of the ``sift_magsac`` baseline (the same pipeline as every strategy)
create = backend_strategy_factory(_sift_backend, SiftOptions)
