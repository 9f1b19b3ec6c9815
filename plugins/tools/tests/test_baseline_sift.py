"""The SIFT baseline keeps one keypoint per image location: OpenCV gives a location one keypoint
per orientation peak, and kept, one ground point would count as several inliers. On the README's
demo imagery: its features repeat no (x, y), its keypoint budget counts distinct points, and a
match's inlier correspondences repeat no row. On the shipped Zurich orthophoto: it describes
about its budget, not every keypoint, and its features are, bit for bit, those that describing
every keypoint and then choosing gives."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.features import Features
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher_tools import baselines
from c3_matcher_tools.baselines import FIRST_PASS_FACTOR, SiftBackend, distinct_strongest

from .conftest import C3

DATA = Path(__file__).resolve().parents[3] / "data"
DEMO = DATA / "demo"
ZURICH = DATA / "imagery" / "open_orthophotos" / "swissimage_zurich_1091-322_00_0p5m.tif"
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


def _prepared(path: Path) -> PreparedImage:
    """The image at ``path`` prepared as a tile is (Zurich's 875 x 600 px: padded, the pad
    masked)."""
    rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    return FramePreprocessor(RULE).prepare_tile(np.asarray(rgb, np.uint8))


def _left_quarter(image: PreparedImage) -> PreparedImage:
    """``image`` valid on its left quarter only, its pixels kept: most of its strongest
    keypoints lie outside the mask."""
    valid = np.zeros_like(image.valid)
    valid[:, : valid.shape[1] // 4] = True
    return dataclasses.replace(image, valid=valid & image.valid)


def _query_like(image: PreparedImage) -> PreparedImage:
    """``image`` inside a quadrilateral, black outside, as a rendered query's footprint is."""
    height, width = image.valid.shape
    corners = np.array([[0.1, 0.3], [0.6, 0.05], [0.95, 0.6], [0.4, 0.97]]) * (width, height)
    valid = np.zeros((height, width), np.uint8)
    cv2.fillPoly(valid, [corners.astype(np.int32)], (1,))
    pixels = np.where(valid[..., None] > 0, image.image, 0).astype(np.uint8)
    return dataclasses.replace(image, image=pixels, valid=valid > 0)


def _every_keypoint_described(image: PreparedImage, budget: int) -> Features:
    """The extraction that describes every keypoint inside the mask, then keeps one per location
    and the budget: what the baseline's features must equal."""
    grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
    keypoints, desc = cv2.SIFT.create().detectAndCompute(grey, image.valid.astype(np.uint8) * 255)
    n = len(keypoints)
    pts = np.array([k.pt for k in keypoints], np.float32).reshape(n, 2)
    scores = np.array([k.response for k in keypoints], np.float32).reshape(n)
    angles = np.array([k.angle for k in keypoints], np.float32).reshape(n)
    keep = distinct_strongest(pts, scores, angles, budget)
    described = np.asarray(desc, np.float32)
    return Features(pts[keep], described[keep], scores[keep], image.engine_size)


class _CountingSift:
    """An OpenCV SIFT that notes how many keypoints each call describes."""

    def __init__(self, sift: cv2.SIFT, described: list[int]) -> None:
        self._sift, self._described = sift, described

    def detectAndCompute(self, *args: Any) -> Any:
        keypoints, descriptors = self._sift.detectAndCompute(*args)
        self._described.append(len(keypoints))
        return keypoints, descriptors


class _CountingCv2:
    """``cv2`` whose ``SIFT.create`` gives :class:`_CountingSift`."""

    def __init__(self, described: list[int]) -> None:
        self.SIFT, self._described = self, described

    def create(self, *args: Any, **kwargs: Any) -> _CountingSift:
        return _CountingSift(cv2.SIFT.create(*args, **kwargs), self._described)

    def __getattr__(self, name: str) -> Any:
        return getattr(cv2, name)


def _counted(
    monkeypatch: pytest.MonkeyPatch, image: PreparedImage, budget: int
) -> tuple[Features, list[int]]:
    """The baseline's features of ``image`` and the keypoints each of its SIFT calls described."""
    described: list[int] = []
    monkeypatch.setattr(baselines, "cv2", _CountingCv2(described))
    return SiftBackend(RULE, budget).extract(image), described


def test_it_describes_about_its_budget_not_every_keypoint(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a dense orthophoto (over 7000 keypoints) a budget of 512 describes at most twice that
    (and any keypoints tied with the last), in one pass: describing every keypoint took up to
    1.8x the time and made the baseline look slower than it is."""
    image = _prepared(ZURICH)
    grey = cv2.cvtColor(image.image, cv2.COLOR_RGB2GRAY)
    assert len(cv2.SIFT.create().detect(grey, None)) > 7000
    features, described = _counted(monkeypatch, image, 512)
    assert len(features) == 512
    assert len(described) == 1 and described[0] <= FIRST_PASS_FACTOR * 512 + 8, described


@pytest.mark.parametrize(
    ("case", "budget", "passes"),
    [
        ("zurich", 2048, 1),  # dense: the first pass holds the budget
        ("zurich", 16, 2),  # the pad's edge and repeats take over half of the strongest 32
        ("zurich, left quarter valid", 1024, 2),  # the strongest lie outside the mask
        ("zurich, query-like", 500, 1),
        ("demo frame", 2048, 1),  # fewer keypoints than the first pass takes
    ],
)
def test_the_features_are_those_describing_every_keypoint_gives(
    monkeypatch: pytest.MonkeyPatch, case: str, budget: int, passes: int
) -> None:
    """Whichever pass gives them, the keypoints kept, their scores and their descriptors equal,
    bit for bit, those of describing every keypoint inside the mask and then choosing."""
    variants = {"left quarter valid": _left_quarter, "query-like": _query_like}
    if case == "demo frame":
        image = _prepared(DEMO / "frame.jpg")
    else:
        image = variants.get(case.partition(", ")[2], lambda i: i)(_prepared(ZURICH))
    expected = _every_keypoint_described(image, budget)
    features, described = _counted(monkeypatch, image, budget)
    assert len(described) == passes, described
    assert len(features) == len(expected) > 0
    assert np.array_equal(features.keypoints, expected.keypoints)
    assert np.array_equal(features.keypoint_scores, expected.keypoint_scores)
    assert np.array_equal(features.descriptors, expected.descriptors)


def test_config_refuses_an_inlier_threshold_above_the_baselines_budget_as_start_up_does(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The baseline declares its keypoint budget (its options), so ``c3-matcher config``
    refuses what every run with the file would refuse at start-up."""
    from c3_matcher.cli import main

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_MATCHER__STRATEGY", "sift_magsac")
    monkeypatch.setenv("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", "3000")
    assert main(["config"]) == 2
    said = capsys.readouterr().err
    assert "matcher.min_inliers_threshold: 3000 exceeds the 2048 keypoints" in said, said
    monkeypatch.setenv("C3_MATCHER_MATCHER__MAX_KEYPOINTS", "4096")  # no engine caps SIFT's
    assert main(["config"]) == 0
