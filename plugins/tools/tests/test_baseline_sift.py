"""The SIFT baseline keeps one keypoint per image location: OpenCV gives a location one keypoint
per orientation peak, and kept, one ground point would count as several inliers. On the README's
demo imagery: its features repeat no (x, y), its keypoint budget counts distinct points, and a
match's inlier correspondences repeat no row."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.features import Features
from c3_matcher.prepared import InputRule
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher_tools.baselines import SiftBackend, distinct_strongest

from .conftest import C3

DEMO = Path(__file__).resolve().parents[3] / "data" / "demo"
RULE = InputRule(1024, 16)


def _features(name: str, max_keypoints: int = 2048) -> Features:
    """The baseline's features of the demo image ``name``, prepared as a tile is."""
    rgb = cv2.cvtColor(cv2.imread(str(DEMO / name)), cv2.COLOR_BGR2RGB)
    image = FramePreprocessor(RULE).prepare_tile(rgb)
    return SiftBackend(RULE, max_keypoints).extract(image)


def _repeated(rows: NDArray[np.float32]) -> int:
    return len(rows) - len(np.unique(rows, axis=0))


@pytest.mark.parametrize("name", ["frame.jpg", "tile_a.png", "tile_b.png", "tile_c.png"])
def test_features_repeat_no_location(name: str) -> None:
    features = _features(name)
    assert len(features) > 500
    assert _repeated(features.keypoints) == 0
    scores = features.keypoint_scores
    assert np.all(scores[:-1] >= scores[1:])  # strongest first


def test_the_budget_counts_distinct_points() -> None:
    """A budget below what the image holds keeps exactly that many distinct points: the
    strongest of the whole set, in the same order."""
    every, some = _features("tile_b.png"), _features("tile_b.png", max_keypoints=500)
    assert len(some) == 500 and _repeated(some.keypoints) == 0
    assert np.array_equal(some.keypoints, every.keypoints[:500])
    assert np.array_equal(some.descriptors, every.descriptors[:500])


def test_extraction_is_deterministic() -> None:
    first, again = _features("tile_a.png"), _features("tile_a.png")
    assert np.array_equal(first.keypoints, again.keypoints)
    assert np.array_equal(first.descriptors, again.descriptors)


def test_the_choice_does_not_depend_on_the_listing_order() -> None:
    """The same keypoints listed in another order keep the same points: the strongest at each
    location, ties broken by position then angle."""
    points = np.array([[5, 5], [1, 2], [5, 5], [1, 2], [3, 3], [5, 5]], np.float32)
    responses = np.array([0.5, 0.9, 0.5, 0.7, 0.5, 0.6], np.float32)
    angles = np.array([30, 10, 20, 0, 0, 40], np.float32)
    keep = distinct_strongest(points, responses, angles, 10)
    assert keep.tolist() == [1, 5, 4]
    flip = np.arange(len(points))[::-1]
    kept = flip[distinct_strongest(points[flip], responses[flip], angles[flip], 10)]
    assert kept.tolist() == keep.tolist()
    assert distinct_strongest(points, responses, angles, 2).tolist() == [1, 5]
    ties = distinct_strongest(points[[0, 2]], responses[[0, 2]], angles[[0, 2]], 10)
    assert ties.tolist() == [1]  # equal response at one location: the smaller angle


def test_a_match_counts_each_inlier_once(c3: C3, tmp_path: Path) -> None:
    """The README's demo frame against its true tile: every inlier correspondence is a distinct
    (query, tile) pair, so the inlier count counts distinct evidence."""
    proc = c3(
        *("match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")),
        *("--tile-gsd", "0.09682870211490897", "--attitude", "18,0,120"),
        *("--calibration", str(DEMO / "calibration.json"), "--height", "27.112037"),
        *("--strategy", "sift_magsac", "--fdr", str(tmp_path / "fdr.jsonl")),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    best = json.loads(proc.stdout)["per_candidate"][0]
    rows = np.asarray(best["inlier_correspondences"], np.float32)
    assert best["inlier_count"] == len(rows) > 60
    assert _repeated(rows) == 0
