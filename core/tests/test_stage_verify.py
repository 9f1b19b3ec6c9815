"""The verification stage: RANSAC alone, the prior's translation vote, its geometry check and
similarity fallback, the prior of a frame, and the choice among query turns."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import RansacResult, TileId
from c3_matcher.features import Features, RawMatches
from c3_matcher.prepared import PreparedImage
from c3_matcher.prior import GeometricPrior, PriorTolerances
from c3_matcher.stages.failure import CandidateStepError
from c3_matcher.stages.outcomes import TileFeatures
from c3_matcher.stages.query import QueryView
from c3_matcher.stages.verify import SpreadCheck, Verifier, best_turn, frame_prior
from c3_matcher.testing import SequenceRansacFilter

TILE = TileId(18, 47.0, 8.5)
SHIFT = np.array([100.0, 50.0])  # tile = query + SHIFT: the pure translation a prior expects


def _rows(n: int = 40, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).uniform(0, 400, (n, 2))
    return np.hstack([q, q + SHIFT]).astype(np.float32)


class FixedRansac:
    """A RansacFilter double: every row an inlier, ``homography`` as the model."""

    def __init__(self, homography: np.ndarray | None) -> None:
        self.homography = homography
        self.seen: list[int] = []

    def filter(self, rows: np.ndarray, threshold_px: float) -> RansacResult:
        self.seen.append(len(rows))
        h = self.homography
        return RansacResult(rows, 0, 0.5, h, np.ones(len(rows), bool))


def _prior() -> GeometricPrior:
    return GeometricPrior(PriorTolerances(), (200.0, 200.0))


def test_without_a_prior_ransac_decides_with_the_inliers_spread():
    verdict = Verifier(SequenceRansacFilter([(30, 1.5)]), 3.0, None).verify(TILE, 90, _rows(), 55)
    assert verdict.match_set.inlier_count == 30
    assert verdict.match_set.ransac_outlier_count == 5
    assert verdict.match_set.per_candidate_residual_px == 1.5
    assert (verdict.rotation_deg, verdict.raw_matches, verdict.model) == (90, 55, "homography")
    assert isinstance(verdict.check, SpreadCheck) and verdict.check.ok and not verdict.refused


def test_the_prior_votes_out_inconsistent_matches_before_ransac():
    rows = _rows()
    rows[:5, 2:] += 300.0  # five matches that disagree with the translation
    ransac = FixedRansac(np.array([[1, 0, 100], [0, 1, 50], [0, 0, 1]], np.float64))
    verdict = Verifier(ransac, 3.0, _prior()).verify(TILE, 0, rows)
    assert ransac.seen == [35]
    assert verdict.match_set.ransac_outlier_count == 5  # the vote's drops count as outliers
    assert verdict.check is not None and verdict.check.ok and verdict.model == "homography"


def test_a_refused_homography_gives_way_to_the_similarity_the_prior_implies():
    scaled = np.array([[1.5, 0, 100], [0, 1.5, 50], [0, 0, 1]], np.float64)  # beyond the scale
    verdict = Verifier(FixedRansac(scaled), 3.0, _prior()).verify(TILE, 0, _rows())
    assert verdict.model == "similarity" and not verdict.refused
    assert verdict.homography is not None
    assert np.allclose(verdict.homography, [[1, 0, 100], [0, 1, 50], [0, 0, 1]], atol=1e-6)
    assert verdict.match_set.inlier_count == 40


def test_a_homography_refused_with_no_similarity_to_fall_back_on_is_refused():
    scaled = np.array([[1.5, 0, 100], [0, 1.5, 50], [0, 0, 1]], np.float64)
    rows = _rows()
    rows[:, 2:] = rows[:, :2] * 1.5 + SHIFT  # the data itself is scaled: no passing similarity
    verdict = Verifier(FixedRansac(scaled), 3.0, GeometricPrior(PriorTolerances(), (0.0, 0.0)))
    result = verdict.verify(TILE, 0, rows)
    assert result.refused and result.model == "homography"
    assert result.check is not None and "scale" in result.check.reason


def _image(**kw: Any) -> PreparedImage:
    return PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (400, 300), **kw
    )


def test_a_frame_has_a_prior_only_rectified_and_scaled_and_when_enabled():
    tol = PriorTolerances()
    assert frame_prior(_image(), True, tol) is None
    assert frame_prior(_image(nadir_working_px=(200.0, 150.0)), True, tol) is None
    both = _image(nadir_working_px=(200.0, 150.0), working_gsd_m=0.3)
    assert frame_prior(both, False, tol) is None
    prior = frame_prior(both, True, tol)
    assert prior is not None and tuple(prior.centre) == (200.0, 150.0)
    assert prior.footprint is not None and prior.footprint.tolist()[2] == [400.0, 300.0]


class PairBackend:
    label, extract_phase, match_phase = "pair", "disk_forward", "lightglue_match"

    def __init__(self, fail: bool = False) -> None:
        self.fail = fail

    def match(self, query: Features, tile: Features) -> RawMatches:
        if self.fail:
            raise RuntimeError("matcher down")
        idx = np.arange(4, dtype=np.int64)
        return RawMatches(np.stack([idx, idx], axis=1), np.ones(4, np.float32))


def _features() -> Features:
    k = np.arange(8, dtype=np.float32).reshape(4, 2)
    return Features(k, np.zeros((4, 4), np.float32), np.ones(4, np.float32), (16, 16))


def _views(n: int) -> list[QueryView]:
    image = PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (16, 16)
    )
    return [QueryView(90 * i, image, _features()) for i in range(n)]


def _tile() -> TileFeatures:
    image = PreparedImage(
        np.zeros((16, 16, 3), np.uint8), np.ones((16, 16), bool), np.eye(3), (16, 16)
    )
    return TileFeatures("cached", image, _features())


def test_the_best_ranked_turn_is_kept_the_first_on_a_tie():
    ransac = SequenceRansacFilter([(20, 2.0), (30, 2.0), (30, 1.0), (30, 1.0)])
    timings: dict[str, float] = {}
    verdict = best_turn(
        PairBackend(), Verifier(ransac, 3.0, None), _views(4), TILE, _tile(), timings
    )
    assert verdict.rotation_deg == 180 and verdict.raw_matches == 4
    assert set(timings) == {"match", "ransac"}


@pytest.mark.parametrize("where", ["match", "ransac"])
def test_a_failing_match_or_ransac_names_its_phase(where):
    class Broken(SequenceRansacFilter):
        def filter(self, rows: Any, threshold_px: float) -> RansacResult:
            raise ValueError("ransac down")

    backend = PairBackend(fail=where == "match")
    ransac = Broken([(1, 1.0)]) if where == "ransac" else SequenceRansacFilter([(1, 1.0)])
    with pytest.raises(CandidateStepError) as failed:
        best_turn(backend, Verifier(ransac, 3.0, None), _views(1), TILE, _tile(), {})
    phase = "lightglue_match" if where == "match" else "ransac"
    assert (failed.value.phase, failed.value.source) == (phase, "cached")
