"""The geometric prior: translation vote before RANSAC, homography check after.

The pipeline tests run the real OpenCV RANSAC over scripted correspondences from a backend
double: each candidate's matches follow a scripted homography (WORKING query px -> tile px), so
the geometry, not the inlier count, decides. Each of them fails with ``geometric_prior=False``.
"""

from __future__ import annotations

import math
import tracemalloc
import uuid
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import AmbiguousMatchError, InsufficientInliersError
from c3_matcher.features import Features, RawMatches
from c3_matcher.health import RollingHealthWindow
from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.prior import GeometricPrior, PriorTolerances, _densest_cell
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.testing import FakeClock
from c3_matcher.tiles import BytesTileHandle

TILE = 448


def _similarity(deg: float, scale: float, tx: float, ty: float) -> np.ndarray:
    c, s = scale * math.cos(math.radians(deg)), scale * math.sin(math.radians(deg))
    return np.array([[c, -s, tx], [s, c, ty], [0, 0, 1]], dtype=np.float64)


def _rows(h: np.ndarray, n: int, rng: np.random.Generator, noise: float = 0.5) -> np.ndarray:
    q = rng.uniform([20, 20], [300, 220], size=(n, 2))
    t = cv2.perspectiveTransform(q.reshape(-1, 1, 2), h).reshape(-1, 2)
    t += rng.normal(0, noise, t.shape)
    return np.hstack([q, t]).astype(np.float32)


# -- the prior alone ---------------------------------------------------------------------------
def test_translation_vote_keeps_the_consistent_matches_and_drops_random_ones() -> None:
    rng = np.random.default_rng(0)
    prior = GeometricPrior(PriorTolerances(), (160.0, 120.0))
    good = _rows(_similarity(3.0, 1.04, 90.0, 140.0), 60, rng)
    bad = np.hstack([rng.uniform(0, 320, (240, 2)), rng.uniform(0, TILE, (240, 2))]).astype(
        np.float32
    )
    keep = prior.consistent(np.vstack([good, bad]))
    assert keep[:60].all()  # within the stated tolerance: 3 deg, 4 % scale
    assert keep[60:].mean() < 0.1


def test_the_vote_costs_the_same_however_far_apart_the_matches_fall() -> None:
    """A few matches millions of px away (a large height, a mistyped tile GSD) neither fill
    memory nor outvote the consistent ones: a dense vote grid over that range would not fit."""
    rng = np.random.default_rng(1)
    prior = GeometricPrior(PriorTolerances(), (160.0, 120.0))
    good = _rows(_similarity(2.0, 1.02, 40.0, 60.0), 30, rng)
    far = np.array([[10, 10, 5e6, -5e6], [20, 20, -5e6, 5e6], [30, 30, 5e6, 5e6]], np.float32)
    keep = prior.consistent(np.vstack([good, far]))
    assert keep[:30].all() and not keep[30:].any()


@given(st.lists(st.tuples(st.integers(-6, 6), st.integers(-6, 6)), min_size=4, max_size=40))
@settings(max_examples=200, deadline=None)
def test_the_densest_cell_is_the_dense_grids_first_maximum(votes: list[tuple[int, int]]) -> None:
    """Both ways of scoring agree with the dense 3x3 box sum over every cell of the votes' range
    (row-major first maximum)."""
    keys = np.array(votes, dtype=np.int64)
    lo = keys.min(axis=0) - 1
    size = keys.max(axis=0) - lo + 2
    grid = np.zeros((int(size[1]), int(size[0])))
    np.add.at(grid, (keys[:, 1] - lo[1], keys[:, 0] - lo[0]), 1.0)
    summed = cv2.boxFilter(grid, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    row, col = np.unravel_index(int(np.argmax(summed)), summed.shape)
    expected = [col + lo[0], row + lo[1]]
    assert _densest_cell(keys).tolist() == expected  # on a dense grid (small spread)
    assert _densest_cell(keys, dense_cells=0).tolist() == expected  # scored sparsely


def test_the_widest_dense_vote_holds_at_most_12_mb() -> None:
    """Votes spread over a whole 2^20-cell grid: the arrays numpy holds at once stay within the
    bound the README gives (OpenCV's box sum, 4 MB of float32, comes after the int64 counts are
    gone)."""
    keys = np.array([[0, 0], [1021, 1021], [5, 5], [6, 6]], dtype=np.int64)
    tracemalloc.start()
    try:
        _densest_cell(keys)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert 8e6 < peak <= 12.6e6, peak


@pytest.mark.parametrize(
    ("h", "reason"),
    [
        (_similarity(30.0, 1.0, 100, 100), "rotation"),
        (_similarity(0.0, 1.4, 50, 50), "scale"),
        (np.array([[1.0, 0.35, 80], [0.0, 1.0, 90], [0, 0, 1]]), "shear"),
        (np.array([[-1.0, 0.0, 380], [0.0, 1.0, 90], [0, 0, 1]]), "mirrored"),
    ],
)
def test_verify_refuses_a_homography_far_from_a_translation(h: np.ndarray, reason: str) -> None:
    canvas = np.array([[0.0, 0.0], [320.0, 0.0], [320.0, 240.0], [0.0, 240.0]])
    check = GeometricPrior(PriorTolerances(), (160.0, 120.0), canvas).verify(h)
    assert not check.ok and reason in check.reason


def test_verify_accepts_a_translation_within_the_sensor_errors() -> None:
    canvas = np.array([[0.0, 0.0], [320.0, 0.0], [320.0, 240.0], [0.0, 240.0]])
    check = GeometricPrior(PriorTolerances(), (160.0, 120.0), canvas).verify(
        _similarity(-6.0, 0.93, 70.0, 120.0)
    )
    assert check.ok, check.reason
    assert check.rotation_deg == pytest.approx(-6.0, abs=1e-6)
    assert check.scale == pytest.approx(0.93, abs=1e-6)


# -- through the pipeline ----------------------------------------------------------------------
class GeometryBackend:
    """A FeatureBackend double: the query's keypoints are a fixed random set; candidate ``i``
    (tile pixels all ``i + 1``) gets, per its script entry, ``n`` keypoints placed by its
    homography from the query's WORKING positions, plus ``noise`` random ones; ``match`` pairs
    them in order. Every script's homography keeps those keypoints on the tile, as the core
    checks in flight."""

    label = "geometry_backend"
    extract_phase = "extract"
    match_phase = "match"
    input_rule = InputRule(max_long_side=1024, multiple=16)

    def __init__(self, script: list[tuple[np.ndarray, int, int]]) -> None:
        self.script = script
        self.query: PreparedImage | None = None
        self.rng = np.random.default_rng(1)

    def extract(self, image: PreparedImage) -> Features:
        if image.working_from_undistorted is not None:  # the query
            self.query = image
            w, h = image.engine_size
            n = 400
            kp = self.rng.uniform([40, 40], [w - 40, h - 40], size=(n, 2))
        else:
            assert self.query is not None
            mark = int(image.image[TILE // 2, TILE // 2, 0]) - 1
            hom, good, noise = self.script[mark]
            qk = self.query.to_working(self._query_kp[:good])
            tk = cv2.perspectiveTransform(qk.reshape(-1, 1, 2), hom).reshape(-1, 2)
            tk += self.rng.normal(0, 0.4, tk.shape)
            junk = self.rng.uniform(0, TILE, size=(noise, 2))
            kp = np.vstack([tk, junk])
            n = kp.shape[0]
        feats = Features(
            kp.astype(np.float32),
            np.zeros((n, 4), np.float32),
            np.ones(n, np.float32),
            image.engine_size,
        )
        if image.working_from_undistorted is not None:
            self._query_kp = kp
        return feats

    def match(self, query: Features, tile: Features) -> RawMatches:
        n = min(len(query), len(tile))
        idx = np.arange(n, dtype=np.int64)
        return RawMatches(np.stack([idx, idx], axis=1), np.ones(n, np.float32))

    def provenance(self) -> dict[str, Any]:
        return {}


class _Fdr:
    def __init__(self) -> None:
        self.records: list[tuple[str, Any]] = []

    def record(self, kind: str, payload: Any) -> None:
        self.records.append((kind, payload))


def _run(
    script: list[tuple[np.ndarray, int, int]],
    *,
    prior: bool,
    attitude: bool = True,
    ransac: Any = None,
) -> Any:
    clock = FakeClock()
    settings = PipelineSettings(geometric_prior=prior)
    matcher = PipelineMatcher(
        GeometryBackend(script),
        ransac or OpenCvRansacFilter(),
        _Fdr(),
        RollingHealthWindow(clock, settings.min_inliers_threshold),
        clock,
        settings,
    )
    frame = NavCameraFrame(
        uuid.UUID(int=3),
        np.full((240, 320, 3), 128, np.uint8),
        captured_at_ns=1,
        attitude=Attitude(0.0, 0.0, 0.0) if attitude else None,
        height_above_ground_m=90.0,  # focal 300 px, tile GSD 0.3 m/px: working scale 1
    )
    calibration = CameraCalibration.pinhole(320, 240, focal_px=300.0)
    candidates = []
    for i in range(len(script)):
        ok, png = cv2.imencode(".png", np.full((TILE, TILE, 3), i + 1, np.uint8))
        assert ok
        handle = BytesTileHandle(png.tobytes(), f"tile{i}")
        candidates.append(
            RerankCandidate(TileId(18, 47.0 + i / 1000, 8.5), 1.0, handle, gsd_m_per_px=0.3)
        )
    return matcher.match(frame, RerankResult(frame.frame_id, tuple(candidates)), calibration)


TRUE = _similarity(2.0, 1.02, 60.0, 100.0)  # the true tile: a translation within tolerances
WRONG = _similarity(35.0, 1.0, 200.0, -40.0)  # a self-consistent wrong structure, rotated


def test_a_confident_wrong_candidate_is_refused_on_geometry() -> None:
    script = [(WRONG, 160, 40), (TRUE, 90, 150), (_similarity(0, 1, 0, 0), 0, 300)]
    result = _run(script, prior=True)
    assert result.per_candidate[0].tile_id.lat == pytest.approx(47.001)
    assert result.per_candidate[0].inlier_count >= 80  # RANSAC inliers, as the contract says
    refused = result.diagnostics["geometry_refused"]
    assert [r["candidate_index"] for r in refused] == [0]
    assert "rotation" in refused[0]["reason"]


def test_without_the_prior_the_wrong_candidate_wins_unless_the_true_one_rivals_it() -> None:
    """The control: the same script with geometric_prior off ranks the rotated structure first;
    with the true tile at more than half its inliers, placing the frame elsewhere, the frame is
    ambiguous (no fix); with the true tile weaker, the wrong one is the fix."""
    script = [(WRONG, 160, 40), (TRUE, 90, 150), (_similarity(0, 1, 0, 0), 0, 300)]
    with pytest.raises(AmbiguousMatchError, match="candidate 1 .* from candidate 0"):
        _run(script, prior=False)
    result = _run([(WRONG, 160, 40), (TRUE, 70, 150)], prior=False)
    assert result.per_candidate[0].tile_id.lat == pytest.approx(47.0)


def test_only_wrong_geometry_raises_insufficient_inliers() -> None:
    script = [(WRONG, 160, 40), (_similarity(0, 1.5, 10, 10), 120, 40)]
    with pytest.raises(InsufficientInliersError):
        _run(script, prior=True)
    assert _run(script, prior=False).per_candidate[0].inlier_count >= 120


def test_no_attitude_means_no_prior() -> None:
    script = [(WRONG, 160, 40), (TRUE, 70, 150)]
    result = _run(script, prior=True, attitude=False)
    assert result.diagnostics["geometric_prior"] is False
    assert result.diagnostics["geometry_refused"] == []


# -- the prior's own model when the free homography fails ------------------------------------
def test_similarity_ransac_recovers_the_prior_model_among_outliers() -> None:
    rng = np.random.default_rng(4)
    prior = GeometricPrior(PriorTolerances(), (160.0, 120.0))
    good = _rows(TRUE, 80, rng, noise=0.3)
    bad = np.hstack([rng.uniform(0, 320, (120, 2)), rng.uniform(0, TILE, (120, 2))])
    rows = np.vstack([good, bad.astype(np.float32)])
    fit = prior.similarity_ransac(rows, 3.0)
    assert fit is not None
    homography, mask = fit
    assert mask[:80].sum() >= 78 and mask[80:].sum() <= 3
    assert np.allclose(homography, TRUE, atol=0.05 * np.abs(TRUE).max())
    again = prior.similarity_ransac(rows, 3.0)
    assert again is not None and np.array_equal(again[0], homography)  # deterministic
    assert np.array_equal(again[1], mask)
    assert prior.similarity_ransac(rows[:3], 3.0) is None


class _SkewingRansac:
    """The real RANSAC, but its homography is skewed at the nadir point (what a free homography
    fitted to clustered inliers does): the prior's check then fails it."""

    def __init__(self) -> None:
        self._inner = OpenCvRansacFilter()

    def filter(self, correspondences: Any, threshold_px: float) -> Any:
        import dataclasses

        out = self._inner.filter(correspondences, threshold_px)
        if out.homography is None:
            return out
        skew = np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        return dataclasses.replace(out, homography=out.homography @ skew)


def test_a_true_tile_whose_homography_fails_is_kept_on_the_prior_similarity() -> None:
    script = [(TRUE, 120, 60), (_similarity(0, 1, 0, 0), 0, 300)]
    result = _run(script, prior=True, ransac=_SkewingRansac())
    best = result.per_candidate[0]
    assert result.diagnostics["input_index"][0] == 0
    assert result.diagnostics["models"][0] == "similarity"
    assert best.inlier_count >= 110  # the similarity's own RANSAC inliers
    assert best.per_candidate_residual_px < 1.5
    assert result.diagnostics["geometry_refused"] == []
    hom = result.diagnostics["homographies"][0]
    assert np.allclose(hom[2], [0, 0, 1]) and np.allclose(hom, TRUE, atol=0.05 * 100)


def test_the_similarity_does_not_rescue_wrong_geometry() -> None:
    script = [(WRONG, 160, 40), (_similarity(0, 1.5, 10, 10), 120, 40)]
    with pytest.raises(InsufficientInliersError):
        _run(script, prior=True, ransac=_SkewingRansac())


def test_a_homography_that_passes_keeps_the_homography_model() -> None:
    script = [(TRUE, 120, 60)]
    result = _run(script, prior=True)
    assert result.diagnostics["models"] == ["homography"]
