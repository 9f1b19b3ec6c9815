"""OpenCvRansacFilter on real correspondences (SIFT on a real orthophoto warped by a known
homography), plus the degenerate cases."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.config import MatcherSettings
from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.prior import GeometricPrior, PriorTolerances
from c3_matcher.ransac import (
    OpenCvRansacFilter,
    homography_residuals,
    refit,
    spread_ratio,
)
from c3_matcher.stages.verify import SpreadCheck, Verifier

REPO = Path(__file__).resolve().parents[2]
TILE = TileId(18, 47.0, 8.5)
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


def test_the_configured_seed_is_the_one_opencv_draws_with(real_correspondences, monkeypatch):
    """``[matcher] ransac_seed`` seeds OpenCV's generator: the USAC parameters of each call
    carry the filter's seed, the configured one for the filter ``[matcher]`` asks for."""
    states: list[int] = []
    real_find = cv2.findHomography

    def spy(src, dst, *args):
        if args and isinstance(args[0], cv2.UsacParams):
            states.append(args[0].randomGeneratorState)
        return real_find(src, dst, *args)

    monkeypatch.setattr(cv2, "findHomography", spy)
    OpenCvRansacFilter.from_settings(MatcherSettings(ransac_seed=7)).filter(
        real_correspondences, 3.0
    )
    OpenCvRansacFilter(seed=12345).filter(real_correspondences, 3.0)
    assert states == [7, 12345]


def test_the_seed_picks_among_unclear_inliers_and_gives_the_same_pick_again(
    real_correspondences,
):
    """Where inliers are not clear cut (every tile point 1.5 px off, a third 1.5 px more,
    against a 2 px threshold) other seeds may keep other inliers: the seed is what makes the
    answer repeatable, and each seed gives its own answer again bit for bit."""
    rows = noisy(real_correspondences)
    rows[:, 2:4] += np.random.default_rng(5).normal(0.0, 1.5, (len(rows), 2)).astype(np.float32)
    picks = {
        seed: OpenCvRansacFilter(seed=seed).filter(rows, 2.0).inlier_correspondences.tobytes()
        for seed in range(6)
    }
    assert len(set(picks.values())) > 1
    for seed, pick in picks.items():
        again = OpenCvRansacFilter(seed=seed).filter(rows, 2.0)
        assert again.inlier_correspondences.tobytes() == pick


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


def test_a_refit_keeping_exactly_the_floor_is_made(real_correspondences):
    """The floor is the least a refit may keep: one keeping exactly that many inliers is made,
    one that would keep one fewer than the floor is not."""
    result = OpenCvRansacFilter().filter(noisy(real_correspondences), threshold_px=3.0)
    residuals = homography_residuals(result.homography, result.inlier_correspondences)
    kept = int((residuals <= 1.5).sum())
    assert 60 <= kept < result.inlier_count
    tight = refit(result, 1.5, floor=kept)
    assert tight is not result and tight.inlier_count == kept
    assert refit(result, 1.5, floor=kept + 1) is result


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
    configured = MatcherSettings(refit_threshold_px=1.5, min_inliers_threshold=80)
    asked = OpenCvRansacFilter.from_settings(configured)
    assert (asked.refit_px, asked.refit_floor) == (1.5, 80)


def on_a_line(noise_px: float) -> np.ndarray:
    """100 query points along a 450 px line and their tile points, a pure (5, 7) shift of them,
    with ``noise_px`` (sigma) Gaussian noise on both sides: matches along a road or field edge."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 400.0, 100)
    query = np.c_[t, 0.5 * t + 10.0]
    tile = query + np.array([5.0, 7.0])
    noise = rng.normal(0, noise_px, (2, *query.shape))
    return np.c_[query + noise[0], tile + noise[1]].astype(np.float32)


@pytest.mark.parametrize("noise_px", [0.0, 0.3])
@pytest.mark.parametrize("refit_px", [0.0, 2.0])
def test_inliers_on_one_line_are_refused_where_no_prior_pins_them(noise_px, refit_px):
    """A homography fitted to points on (or near) one line fits them to a fraction of a pixel
    while its terms across the line are noise: without a geometric prior, refused on geometry
    naming the spread, not handed on as a confident fit."""
    rows = on_a_line(noise_px)
    ransac = OpenCvRansacFilter(refit_px=refit_px, refit_floor=60)
    assert ransac.filter(rows, 3.0).inlier_count >= 60  # RANSAC itself takes them
    verdict = Verifier(ransac, 3.0, None).verify(TILE, 0, rows)
    assert verdict.refused and isinstance(verdict.check, SpreadCheck)
    assert verdict.check.spread < 0.01 and "inliers on one line" in verdict.check.reason


def test_a_refit_that_keeps_only_a_line_is_refused():
    """The spread is checked on the final inliers: a refit that keeps only the precise points,
    all on one line, leaves nothing to fix the homography across it."""
    line = on_a_line(0.0)
    rng = np.random.default_rng(1)
    query = rng.uniform(0, 400, (40, 2))
    angle = rng.uniform(0, 2 * np.pi, 40)
    tile = query + [5.0, 7.0] + 1.5 * np.c_[np.cos(angle), np.sin(angle)]  # 1.5 px off, all
    rows = np.r_[line, np.c_[query, tile].astype(np.float32)]
    assert not Verifier(OpenCvRansacFilter(), 3.0, None).verify(TILE, 0, rows).refused
    refitted = Verifier(OpenCvRansacFilter(refit_px=0.5, refit_floor=60), 3.0, None)
    assert refitted.verify(TILE, 0, rows).refused


def _band(spread: float) -> np.ndarray:
    """41 x 9 query points on a grid 400 px long whose :func:`spread_ratio` is ``spread``, and
    their tile points, a pure (5, 7) shift of them."""
    xs, ys = np.meshgrid(np.linspace(0.0, 400.0, 41), np.linspace(0.0, 1.0, 9))
    grid = np.c_[xs.ravel(), ys.ravel()]
    grid[:, 1] *= spread / spread_ratio(grid)
    return np.c_[grid, grid + np.array([5.0, 7.0])].astype(np.float32)


@pytest.mark.parametrize(("spread", "refused"), [(0.19, True), (0.21, False)])
def test_the_spread_check_refuses_just_under_its_ratio_and_passes_just_over(spread, refused):
    """:data:`MIN_SPREAD_RATIO` is where the check turns: inliers a little narrower than a
    fifth of their length are refused without a prior, a little wider pass."""
    rows = _band(spread)
    assert spread_ratio(rows[:, 0:2]) == pytest.approx(spread, abs=1e-3)
    verdict = Verifier(OpenCvRansacFilter(), 3.0, None).verify(TILE, 0, rows)
    assert isinstance(verdict.check, SpreadCheck)
    assert verdict.refused is refused and verdict.check.ok is not refused


def test_with_a_prior_the_prior_decides():
    """Where attitude and height give a geometric prior, its own check (and its similarity
    fallback) pins what a line leaves free: the spread check is not its."""
    canvas = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 300.0], [0.0, 300.0]])
    prior = GeometricPrior(PriorTolerances(), (200.0, 150.0), canvas)
    verdict = Verifier(OpenCvRansacFilter(), 3.0, prior).verify(TILE, 0, on_a_line(0.3))
    assert not isinstance(verdict.check, SpreadCheck)


def test_well_spread_inliers_pass_the_check_unchanged(real_correspondences):
    """Real correspondences spread over the image: the check passes and the verdict carries
    RANSAC's result bit for bit."""
    corr = noisy(real_correspondences)
    for f in (OpenCvRansacFilter(), OpenCvRansacFilter(refit_px=1.5, refit_floor=60)):
        plain = f.filter(corr, 3.0)
        verdict = Verifier(f, 3.0, None).verify(TILE, 0, corr)
        assert isinstance(verdict.check, SpreadCheck) and verdict.check.ok
        assert verdict.check.spread > 0.5 and plain.inlier_count >= 200
        got = verdict.match_set.inlier_correspondences
        assert got.tobytes() == plain.inlier_correspondences.tobytes()
        assert verdict.homography is not None and plain.homography is not None
        assert verdict.homography.tobytes() == plain.homography.tobytes()


def test_spread_ratio_is_width_over_length_whatever_the_pose():
    """Unitless and unchanged by a similarity: a filled w x l rectangle gives about w / l
    however it is turned, scaled or placed; a line or a single point gives 0."""
    rng = np.random.default_rng(2)
    box = rng.uniform(0, 1, (4000, 2)) * [400.0, 80.0]
    assert spread_ratio(box) == pytest.approx(0.2, abs=0.01)
    turn = np.array([[np.cos(1.0), -np.sin(1.0)], [np.sin(1.0), np.cos(1.0)]])
    assert spread_ratio(3.5 * box @ turn.T + [900.0, -40.0]) == pytest.approx(spread_ratio(box))
    assert spread_ratio(np.c_[np.arange(9.0), 2 * np.arange(9.0)]) == pytest.approx(0, abs=1e-9)
    assert spread_ratio(np.tile([[4.0, 4.0]], (5, 1))) == 0.0
    assert spread_ratio(np.zeros((0, 2))) == 0.0
    with pytest.raises(InvalidInputError, match="points"):
        spread_ratio(np.zeros((5, 3)))
