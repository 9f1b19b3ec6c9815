"""The refine pass: the best-ranked candidate's query re-rendered through its
first homography into the tile's pixel grid, extracted and matched again.

Scripted doubles for the control flow (when it runs, which pass is kept, what a failure does,
the FDR records), and the geometry of the re-rendered query on a synthetic ground texture. The
real path (xfeat on the shipped flight with attitude error) is in the tools' tests
(``test_refine_real.py``).
"""

from __future__ import annotations

import uuid
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher.config import load_settings
from c3_matcher.dto import Attitude, CameraCalibration, NavCameraFrame
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.pipeline import PipelineSettings
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.testing import (
    FakeBackend,
    ScriptedCandidate,
    ScriptedRig,
    SequenceRansacFilter,
)

S = ScriptedCandidate
ON = PipelineSettings(refine=True)


# -- settings -------------------------------------------------------------------------------
def test_refine_is_off_by_default_and_reaches_the_pipeline(tmp_path):
    assert not PipelineSettings().refine
    assert not load_settings(env={}).matcher.refine
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nrefine = true\n")
    assert PipelineSettings.from_settings(load_settings(toml, env={}).matcher).refine
    env = {"C3_MATCHER_MATCHER__REFINE": "true"}
    assert PipelineSettings.from_settings(load_settings(env=env).matcher).refine


# -- control flow (scripted doubles) --------------------------------------------------------
def test_off_one_query_extraction_and_no_record(fdr, logs):
    rig = ScriptedRig([S(120), S(80)], fdr)
    result = rig.match()
    assert rig.query_extractions == 1
    assert result.diagnostics["refine"] is None
    assert "refine" not in fdr.of_kind("matcher.frame_done")[0]


def _refine_rig(fdr: Any, outcomes: list[tuple[int, float]], **kw: Any) -> ScriptedRig:
    """Two candidates; RANSAC answers candidate 0, candidate 1, then the refine pass."""
    return ScriptedRig([S(), S()], fdr, ON, ransac=SequenceRansacFilter(outcomes), **kw)


def test_the_refined_pass_replaces_the_first_when_it_ranks_better(fdr, logs):
    rig = _refine_rig(fdr, [(80, 1.5), (50, 1.0), (95, 0.9)])
    result = rig.match()
    assert rig.query_extractions == 2  # the frame, then its re-rendering: one more
    assert len(rig.lightglue.calls) == 3 and rig.lightglue.calls[-1] == 0  # against tile 0
    assert [c.inlier_count for c in result.per_candidate] == [95, 50]
    assert result.reprojection_residual_px == 0.9
    assert result.diagnostics["input_index"] == [0, 1]
    record = {"candidate_index": 0, "inliers_before": 80, "inliers_after": 95, "kept": True}
    assert result.diagnostics["refine"] == record
    (done,) = fdr.of_kind("matcher.frame_done")
    assert done["refine"] == record and done["best_inlier_count"] == 95
    assert "refine" in result.diagnostics["per_candidate_timings_ms"][0]


@pytest.mark.parametrize("refined", [(70, 0.5), (80, 1.5), (0, 0.0)])
def test_a_refined_pass_that_ranks_no_better_leaves_the_first(fdr, logs, refined):
    rig = _refine_rig(fdr, [(80, 1.5), (50, 1.0), refined])
    result = rig.match()
    assert [c.inlier_count for c in result.per_candidate] == [80, 50]
    assert result.reprojection_residual_px == 1.5
    assert result.diagnostics["refine"]["kept"] is False
    assert result.diagnostics["refine"]["reason"] == "ranks no better than the first pass"


def test_refine_can_lift_the_best_over_the_threshold(fdr, logs):
    result = _refine_rig(fdr, [(40, 1.0), (50, 1.0), (75, 1.2)]).match()
    assert result.diagnostics["input_index"] == [1, 0]  # candidate 1 ranked first and refined
    assert [c.inlier_count for c in result.per_candidate] == [75, 40]
    assert result.diagnostics["refine"]["candidate_index"] == 1


def test_insufficient_after_refine_records_it(fdr, logs):
    with pytest.raises(InsufficientInliersError) as info:
        _refine_rig(fdr, [(30, 1.0), (20, 1.0), (45, 1.0)]).match()
    assert info.value.best_inlier_count == 45
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["refine"] == {
        "candidate_index": 0,
        "inliers_before": 30,
        "inliers_after": 45,
        "kept": True,
    }


class _FailingSecondQuery:
    """A FakeBackend whose second query extraction (the refine pass's) raises."""

    def __init__(self, inner: FakeBackend) -> None:
        self._inner = inner
        self.query_calls = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def extract(self, image: PreparedImage) -> Any:
        if int(image.image.reshape(-1)[0]) == 255:
            self.query_calls += 1
            if self.query_calls == 2:
                raise RuntimeError("scripted refine failure")
        return self._inner.extract(image)


def test_a_refine_failure_leaves_the_first_pass_and_is_logged_not_dropped(fdr, logs):
    rig = _refine_rig(fdr, [(80, 1.5), (50, 1.0)], wrap_backend=_FailingSecondQuery)
    result = rig.match()
    assert [c.inlier_count for c in result.per_candidate] == [80, 50]
    assert result.candidates_dropped == 0
    assert fdr.of_kind("matcher.backbone_error") == []
    assert result.diagnostics["refine"]["kept"] is False
    assert "scripted refine failure" in result.diagnostics["refine"]["reason"]
    (warning,) = logs.of_kind("c3.matcher.refine_failed")
    assert warning["level"] == "WARNING"


# -- geometry -------------------------------------------------------------------------------
def _ground(size: int, seed: int = 5) -> np.ndarray:
    """A smooth random ground texture, RGB uint8."""
    rng = np.random.default_rng(seed)
    noise = rng.random((size // 8, size // 8, 3)).astype(np.float32)
    big = cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.asarray(np.clip(big * 255, 0, 255), np.uint8)


def test_the_refined_query_shows_the_tile_and_maps_back_to_the_query_working_px():
    """A level nadir frame of a texture; the 'tile' is that frame's working image warped by a
    known homography H (rotation, scale, shift). Re-rendered through H, the query must look like
    the tile where they overlap, and its engine px must map back through H^-1."""
    w, h, f = 192, 160, 200.0
    calibration = CameraCalibration.pinhole(w, h, focal_px=f)
    frame = NavCameraFrame(
        uuid.UUID(int=3),
        _ground(256)[:h, :w].copy(),
        1,
        Attitude.from_degrees(0.0, 0.0, 0.0),
        height_above_ground_m=100.0,
    )
    pre = FramePreprocessor(InputRule(max_long_side=512, multiple=16), border_erode_px=2)
    geometry = pre.query_geometry(frame, calibration, 0.5)  # working px = 0.5 m
    query = pre.render_query(frame, calibration, geometry)
    a = np.deg2rad(8.0)
    homography = np.array(
        [
            [1.05 * np.cos(a), -1.05 * np.sin(a), 30.0],
            [1.05 * np.sin(a), 1.05 * np.cos(a), 20.0],
            [0.0, 0.0, 1.0],
        ]
    )
    working = cv2.warpAffine(
        query.image, np.linalg.inv(query.working_from_engine)[:2], query.working_size
    )
    tile_size = (448, 448)
    tile = cv2.warpPerspective(working, homography, tile_size)

    refined_geometry = pre.refined_geometry(geometry, homography, tile_size)
    assert refined_geometry is not None
    refined = pre.render_query(frame, calibration, refined_geometry)
    # engine px -> working px (query) -> tile px through H lands on the engine px + the crop
    ys, xs = np.nonzero(refined.valid)
    pts = np.stack([xs, ys], axis=1).astype(np.float64)
    back = refined.to_working(pts)
    assert np.allclose(refined.to_engine(back), pts, atol=1e-6)
    in_tile = cv2.perspectiveTransform(back.reshape(-1, 1, 2), homography).reshape(-1, 2)
    offset = in_tile - pts
    assert np.allclose(offset, offset[0], atol=1e-6)  # a pure crop shift: same scale, no turn
    ox, oy = np.rint(offset[0]).astype(int)
    # the pixels: the re-rendered query is the tile's crop (two resamplings apart)
    inside = refined.valid & (
        tile[oy : oy + refined.image.shape[0], ox : ox + refined.image.shape[1]].sum(axis=2) > 0
    )
    crop = tile[oy : oy + refined.image.shape[0], ox : ox + refined.image.shape[1]]
    diff = np.abs(refined.image.astype(int) - crop.astype(int))[inside].mean()
    wrong = np.abs(refined.image.astype(int) - np.roll(crop, 6, axis=1).astype(int))[inside].mean()
    assert inside.sum() > 0.5 * refined.valid.sum()
    assert diff < 6 and wrong > 3 * diff
    # the prior's view is unchanged: same working frame, same lens
    assert refined.working_from_undistorted is not None
    assert np.array_equal(refined.working_from_undistorted, query.working_from_undistorted)


@pytest.mark.parametrize(
    "homography",
    [
        np.array([[1.0, 0.0, 5000.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # off the tile
        np.zeros((3, 3)),  # degenerate
        np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.01, 0.0, 1.0]]),  # crosses the horizon
    ],
)
def test_no_refined_geometry_for_a_homography_that_leaves_no_footprint(homography):
    w, h = 192, 160
    calibration = CameraCalibration.pinhole(w, h, focal_px=200.0)
    frame = NavCameraFrame(
        uuid.UUID(int=4),
        _ground(256)[:h, :w].copy(),
        1,
        Attitude.from_degrees(0, 0, 0),
        height_above_ground_m=100.0,
    )
    pre = FramePreprocessor(InputRule(max_long_side=512, multiple=16))
    geometry = pre.query_geometry(frame, calibration, 0.5)
    assert pre.refined_geometry(geometry, homography, (448, 448)) is None


def test_the_refined_render_shrinks_the_source_by_its_own_scale_not_the_first_pass_s():
    """A 4000x3000 camera 100 m up over 512-px tiles at 5 cm/px: the first pass's image is the
    working canvas cut to 1024 px (about 4.9 original px per engine px), the refine image the
    tile's own grid (about 1.5). The refine render kept the first figure and area-shrank the
    frame 3x more than its grid needs: a smeared image for the pass meant to add precision."""
    from c3_matcher import camera as cam

    cal = CameraCalibration.pinhole(4000, 3000, 3000.0)
    frame = NavCameraFrame(
        uuid.uuid4(),
        np.zeros((3000, 4000, 3), np.uint8),
        1,
        attitude=Attitude.from_degrees(3, 2, 40),
        height_above_ground_m=100.0,
    )
    pre = FramePreprocessor(InputRule(1024, 16))
    first = pre.query_geometry(frame, cal, 0.05)
    nx, ny = first.nadir_working_px
    refined = pre.refined_geometry(
        first, np.array([[1, 0, 256 - nx], [0, 1, 256 - ny], [0, 0, 1.0]]), (512, 512)
    )
    assert refined is not None

    def original_per_engine(g):
        to_undistorted = np.linalg.inv(g.working_from_undistorted) @ g.working_from_engine
        p, e = np.asarray(g.content_size, float) / 2, 1e-3
        f = lambda q: cam.apply_homography(to_undistorted, [q])[0]  # noqa: E731
        step = np.eye(2) * e
        jac = np.stack([(f(p + step[0]) - f(p)) / e, (f(p + step[1]) - f(p)) / e], axis=1)
        return float(np.sqrt(abs(np.linalg.det(jac))))

    assert first.nadir_shrink == pytest.approx(original_per_engine(first), rel=0.02)
    assert refined.nadir_shrink == pytest.approx(original_per_engine(refined), rel=0.02)
    assert refined.nadir_shrink < first.nadir_shrink / 3
