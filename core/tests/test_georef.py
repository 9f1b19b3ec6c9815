"""Where a match puts the frame: the best candidate's map from UNDISTORTED query px to tile px.

When the geometric prior keeps its similarity (the free homography of the inliers failed its
check), the georeference goes through that similarity; a free homography refitted over the same
inliers brought back the extrapolation the prior had refused (metres off at the frame centre)."""

from __future__ import annotations

import uuid

import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    CandidateMatchSet,
    MatchResult,
    NavCameraFrame,
    TileId,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import (
    best_query_to_tile,
    fit_query_to_tile,
    footprint_lonlat,
    georeference_result,
    lonlat_to_tile_px,
    tile_px_to_lonlat,
)
from c3_matcher.prepared import InputRule
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.prior import GeometricPrior, PriorTolerances

from .test_prior import TILE, TRUE, _run, _SkewingRansac

GSD_M = 0.3


def test_the_pipeline_hands_over_the_kept_model_from_undistorted_px() -> None:
    """``query_to_tile`` is the kept model (here the similarity) composed with the query's
    rectification; the georeference and its ``best_homography`` use it."""
    result = _run([(TRUE, 120, 60)], prior=True, ransac=_SkewingRansac())
    assert result.diagnostics["models"] == ["similarity"]
    (kept,) = result.diagnostics["query_to_tile"]
    calibration = CameraCalibration.pinhole(320, 240, focal_px=300.0)
    # focal 300 px at 90 m over a 0.3 m tile, level: WORKING px are UNDISTORTED px shifted
    similarity = result.diagnostics["homographies"][0]
    assert np.allclose(kept[:2, :2], similarity[:2, :2]) and np.allclose(kept[2], [0, 0, 1])
    assert np.array_equal(best_query_to_tile(result, calibration), kept)
    geo = georeference_result(result, calibration, [(TILE, TILE)])
    assert np.array_equal(np.asarray(geo["best_homography"]), kept)


def test_a_homography_the_prior_accepts_is_refitted_over_every_inlier() -> None:
    result = _run([(TRUE, 120, 60)], prior=True)
    calibration = CameraCalibration.pinhole(320, 240, focal_px=300.0)
    assert result.diagnostics["models"] == ["homography"]
    refit = fit_query_to_tile(result.per_candidate[0].inlier_correspondences, calibration)
    assert refit is not None
    assert np.array_equal(best_query_to_tile(result, calibration), refit)


def _band_trials(trials: int) -> tuple[list[float], list[float]]:
    """Centre errors (m) of a tilted, distorted 640x480 frame at 100 m whose inliers lie along
    one 10-px band (a shoreline), tile points with 1 px of noise, in the trials where the prior
    refuses the free homography and keeps its similarity: (through the kept similarity,
    through a free homography refitted over the same inliers)."""
    w, h = 640, 480
    calibration = CameraCalibration.pinhole(w, h, 560.0, (-0.12, 0.03, 0.0005, -0.0004, 0.0))
    attitude = Attitude.from_degrees(5.0, -8.0, 30.0)
    frame = NavCameraFrame(uuid.UUID(int=1), np.zeros((h, w, 3), np.uint8), 0, attitude, 100.0)
    pre = FramePreprocessor(InputRule(1024, 16))
    query = pre.render_query(frame, calibration, pre.query_geometry(frame, calibration, GSD_M))
    assert query.working_from_undistorted is not None and query.nadir_working_px is not None
    ww, wh = query.working_size
    canvas = np.array([[0.0, 0.0], [ww, 0.0], [ww, wh], [0.0, wh]])
    prior = GeometricPrior(PriorTolerances(), query.nadir_working_px, canvas)
    truth_model = np.array([[1.0, 0.0, 40.0], [0.0, 1.0, -25.0], [0.0, 0.0, 1.0]])  # tile px
    centre = np.array([[calibration.K[0, 2], calibration.K[1, 2]]])
    truth = cam.apply_homography(truth_model @ query.working_from_undistorted, centre)[0]
    rng = np.random.default_rng(1)
    kept_m: list[float] = []
    refit_m: list[float] = []
    for _ in range(trials):
        x = rng.uniform(0, w - 1, 60)
        y = np.clip(90 + 0.25 * (x - 320) + rng.uniform(-5, 5, 60), 0, h - 1)
        original = np.stack([x, y], axis=1)
        working = query.original_to_working(original)
        tile = cam.apply_homography(truth_model, working) + rng.normal(0, 1.0, working.shape)
        rows = np.hstack([working, tile]).astype(np.float32)
        free = fit_query_to_tile(rows, None)
        if free is None or prior.verify(free).ok:
            continue  # the free homography is kept: not the case here
        fit = prior.similarity_ransac(rows, 3.0)
        if fit is None or not prior.verify(fit[0]).ok:
            continue
        similarity, mask = fit
        inliers = np.hstack([original[mask], tile[mask]]).astype(np.float32)
        result = MatchResult(
            uuid.UUID(int=1),
            (CandidateMatchSet(TileId(18, 47.0, 8.5), len(inliers), inliers, 0, 0.5),),
            0,
            0.5,
            0,
            "test",
            1,
            0,
            {"models": ["similarity"], "query_to_tile": [query.from_undistorted(similarity)]},
        )
        for model, errors in (
            (best_query_to_tile(result, calibration), kept_m),
            (fit_query_to_tile(inliers, calibration), refit_m),
        ):
            assert model is not None
            errors.append(
                float(np.linalg.norm(cam.apply_homography(model, centre)[0] - truth)) * GSD_M
            )
    return kept_m, refit_m


def test_the_centre_of_a_frame_kept_on_the_similarity_is_where_the_similarity_puts_it() -> None:
    kept_m, refit_m = _band_trials(300)
    assert len(kept_m) >= 100  # the case is common with one band of inliers
    assert np.percentile(kept_m, 95) < 0.5  # measured 0.15 m
    assert np.median(refit_m) > 1.0  # measured 2.6 m: what the georeference gave before


def _skewed(distortion: tuple[float, ...]) -> CameraCalibration:
    k = np.array([[300.0, 20.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
    return CameraCalibration(k, np.array(distortion), (320, 240))


def test_a_skewed_lens_without_distortion_is_georeferenced_as_with_a_vanishing_one() -> None:
    """The footprint takes the image boundary into UNDISTORTED px as the fitted homography takes
    the inliers, distortion or none: a skew of 20 px with every coefficient 0 gives the footprint
    of one with a coefficient of 1e-15 (skipping the undistortion sheared it by metres)."""
    truth = np.array([[0.9, 0.1, 40.0], [-0.1, 0.9, 30.0], [1e-4, 0.0, 1.0]])
    rng = np.random.default_rng(3)
    original = rng.uniform([0, 0], [319, 239], (50, 2))
    undistorted = cam.undistort_points(original, _skewed((1e-15, 0.0, 0.0, 0.0, 0.0)))
    rows = np.hstack([original, cam.apply_homography(truth, undistorted)])
    tile_id = TileId(18, 47.0, 8.5)
    placed = []
    for distortion in ((0.0, 0.0, 0.0, 0.0, 0.0), (1e-15, 0.0, 0.0, 0.0, 0.0)):
        calibration = _skewed(distortion)
        hom = fit_query_to_tile(rows, calibration)
        assert hom is not None
        placed.append(footprint_lonlat(hom, tile_id, (512, 512), calibration, GSD_M))
    (centre_a, ring_a), (centre_b, ring_b) = placed
    assert np.allclose(centre_a, centre_b, rtol=0, atol=1e-6)
    assert np.allclose(ring_a, ring_b, rtol=0, atol=1e-6)


@pytest.mark.parametrize("lat", [-90.0, 90.0, 85.06, -85.052])
def test_a_tile_id_beyond_web_mercators_latitudes_is_refused_by_name(lat: float) -> None:
    """A pole's id gave an OverflowError, or a centre at -90 deg and longitudes of 1e12 deg."""
    tile_id = TileId(15, lat, 0.0)
    says = r"tile_id.lat: .* beyond web mercator's latitude limit, \+-85.0511 deg"
    with pytest.raises(InvalidInputError, match=says):
        tile_px_to_lonlat(tile_id, (256, 256), [[0.0, 0.0]])
    with pytest.raises(InvalidInputError, match=says):
        lonlat_to_tile_px(tile_id, (256, 256), [[0.0, lat]], tile_gsd_m=0.3)
    calibration = CameraCalibration.pinhole(320, 240, focal_px=300.0)
    with pytest.raises(InvalidInputError, match=says):
        footprint_lonlat(np.eye(3), tile_id, (256, 256), calibration, GSD_M)


def test_a_tile_id_just_within_web_mercators_latitudes_is_georeferenced() -> None:
    (lon, lat), ring = footprint_lonlat(
        np.eye(3), TileId(21, 85.05, 0.0), (320, 240), CameraCalibration.pinhole(320, 240, 300.0)
    )
    assert abs(lat - 85.05) < 1e-6 and abs(lon) < 1e-6
    assert np.isfinite(ring).all() and np.abs(ring).max() < 90.0
