"""OpenCvRansacFilter on real correspondences (SIFT on a real orthophoto warped by a known
homography), plus the degenerate cases."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.ransac import OpenCvRansacFilter, homography_residuals, refit

REPO = Path(__file__).resolve().parents[2]
ORTHO = REPO / "data" / "imagery" / "open_orthophotos" / "test_tiled.tif"
H_TRUE = np.array([[0.92, 0.18, 30.0], [-0.15, 0.95, 60.0], [2e-5, -1e-5, 1.0]])


@pytest.fixture(scope="module")
def real_correspondences() -> np.ndarray:
    """SIFT + ratio test between the orthophoto and its warp: real, noisy, with outliers."""
    image = cv2.cvtColor(cv2.imread(str(ORTHO), cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)
    warped = cv2.warpPerspective(image, H_TRUE, (image.shape[1], image.shape[0]))
    sift = cv2.SIFT_create(nfeatures=3000)
    k0, d0 = sift.detectAndCompute(image, None)
    k1, d1 = sift.detectAndCompute(warped, None)
    pairs = cv2.BFMatcher().knnMatch(d0, d1, k=2)
    good = [m for m, n in pairs if m.distance < 0.9 * n.distance]
    rows = [(*k0[m.queryIdx].pt, *k1[m.trainIdx].pt) for m in good]
    return np.asarray(rows, dtype=np.float32)


def test_inliers_agree_with_ground_truth(real_correspondences):
    corr = real_correspondences
    gt_error = homography_residuals(H_TRUE, corr)
    assert (gt_error > 10).sum() > 20, "the fixture must contain real outliers"
    result = OpenCvRansacFilter().filter(corr, threshold_px=3.0)
    assert result.inlier_count >= 200
    assert result.inlier_count + result.ransac_outlier_count == len(corr)
    inlier_gt = homography_residuals(H_TRUE, result.inlier_correspondences)
    assert np.percentile(inlier_gt, 95) < 3.0
    assert result.per_candidate_residual_px < 1.0
    assert result.per_candidate_residual_px == pytest.approx(
        float(np.median(homography_residuals(result.homography, result.inlier_correspondences)))
    )
    assert result.inlier_correspondences.dtype == np.float32
    assert result.inlier_correspondences.shape == (result.inlier_count, 4)


def test_seeded_and_deterministic(real_correspondences):
    a = OpenCvRansacFilter(seed=3).filter(real_correspondences, 3.0)
    b = OpenCvRansacFilter(seed=3).filter(real_correspondences, 3.0)
    assert a.inlier_correspondences.tobytes() == b.inlier_correspondences.tobytes()
    assert a.per_candidate_residual_px == b.per_candidate_residual_px


def test_a_call_in_between_leaves_a_running_call_alone(real_correspondences, monkeypatch):
    """The filter is shared (the stages after the matcher use it too): a call with another
    threshold made while one runs, which is what a second thread can do, changes nothing."""
    ransac = OpenCvRansacFilter()
    alone = ransac.filter(real_correspondences, 3.0)
    real_find = cv2.findHomography
    interrupted: list[bool] = []

    def another_call_first(*args):
        if not interrupted:
            interrupted.append(True)
            ransac.filter(real_correspondences, 60.0)
        return real_find(*args)

    monkeypatch.setattr(cv2, "findHomography", another_call_first)
    crossed = ransac.filter(real_correspondences, 3.0)
    assert interrupted
    assert crossed.inlier_correspondences.tobytes() == alone.inlier_correspondences.tobytes()
    assert crossed.per_candidate_residual_px == alone.per_candidate_residual_px


def test_fewer_than_four_and_degenerate_give_zero_inliers():
    f = OpenCvRansacFilter()
    three = np.array([[0, 0, 1, 1], [5, 5, 6, 6], [9, 1, 10, 2]], np.float32)
    r = f.filter(three, 3.0)
    assert r.inlier_count == 0 and r.ransac_outlier_count == 3 and r.homography is None
    line = np.array([[i, i, 2 * i, 2 * i] for i in range(20)], np.float32)  # collinear
    assert f.filter(line, 3.0).inlier_count == 0
    same = np.tile(np.array([[4, 4, 8, 8]], np.float32), (10, 1))  # one repeated point
    assert f.filter(same, 3.0).inlier_count == 0
    assert f.filter(np.zeros((0, 4), np.float32), 3.0).inlier_count == 0


def test_bad_arguments_are_named():
    f = OpenCvRansacFilter()
    with pytest.raises(InvalidInputError, match="correspondences"):
        f.filter(np.zeros((5, 3), np.float32), 3.0)
    with pytest.raises(InvalidInputError, match="threshold_px"):
        f.filter(np.zeros((5, 4), np.float32), 0.0)


def noisy(corr: np.ndarray) -> np.ndarray:
    """The fixture with 1.5 px (sigma) Gaussian noise on the tile points of a third of the rows:
    inliers of a 3 px threshold at several precisions, as across seasons."""
    rng = np.random.default_rng(3)
    out = corr.copy()
    rows = rng.choice(len(out), size=len(out) // 3, replace=False)
    out[rows, 2:4] += rng.normal(0.0, 1.5, size=(len(rows), 2)).astype(np.float32)
    return out


def test_refit_keeps_the_precise_inliers_and_refits(real_correspondences):
    corr = noisy(real_correspondences)
    result = OpenCvRansacFilter().filter(corr, threshold_px=3.0)
    tight = refit(result, 1.5, floor=60)
    assert 60 <= tight.inlier_count < result.inlier_count
    assert tight.inlier_count + tight.ransac_outlier_count == len(corr)
    assert np.array_equal(corr[tight.inlier_mask], tight.inlier_correspondences)
    assert not (tight.inlier_mask & ~result.inlier_mask).any(), "a subset of RANSAC's inliers"
    assert homography_residuals(result.homography, tight.inlier_correspondences).max() <= 1.5
    before = homography_residuals(H_TRUE, result.inlier_correspondences).mean()
    after = homography_residuals(H_TRUE, tight.inlier_correspondences).mean()
    assert after < 0.8 * before, (before, after)
    assert tight.per_candidate_residual_px == pytest.approx(
        float(np.median(homography_residuals(tight.homography, tight.inlier_correspondences)))
    )
    again = refit(result, 1.5, floor=60)
    assert again.inlier_correspondences.tobytes() == tight.inlier_correspondences.tobytes()
    assert again.homography.tobytes() == tight.homography.tobytes()


def test_refit_never_goes_below_the_floor_and_none_is_identity(real_correspondences):
    result = OpenCvRansacFilter().filter(noisy(real_correspondences), threshold_px=3.0)
    assert refit(result, 0.0) is result
    assert refit(result, 1.5, floor=result.inlier_count) is result
    assert refit(result, 1e-6) is result  # fewer than 4 would remain
    empty = OpenCvRansacFilter().filter(real_correspondences[:3], threshold_px=3.0)
    assert refit(empty, 1.5) is empty


def test_the_filter_applies_its_configured_refit(real_correspondences):
    corr = noisy(real_correspondences)
    plain = OpenCvRansacFilter().filter(corr, threshold_px=3.0)
    refitting = OpenCvRansacFilter(refit_px=1.5, refit_floor=60)
    got = refitting.filter(corr, threshold_px=3.0)
    want = refit(plain, 1.5, floor=60)
    assert got.inlier_correspondences.tobytes() == want.inlier_correspondences.tobytes()
    assert got.inlier_count < plain.inlier_count
    with pytest.raises(InvalidInputError, match="refit_px"):
        OpenCvRansacFilter(refit_px=-1.0)
