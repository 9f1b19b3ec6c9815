"""Rotation search: a frame without attitude tried at 0/90/180/270 deg.

Scripted doubles for the control flow (how many extractions, which turn a candidate keeps, the
FDR records), a dot-pattern backend whose descriptors depend on orientation for the geometry
(coordinates come back in the frame as given), and the real path: the demo frame rectified with
its attitude, turned by 90 deg and given WITHOUT attitude, through the real xfeat engines.

``python core/tests/test_rotation_search.py`` prints the cost figures of docs/accuracy.md
"Rotation search" (frame time on data/demo with xfeat, search off vs on).
"""

from __future__ import annotations

import json
import statistics
import sys
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from c3_matcher.config import load_settings
from c3_matcher.dto import (
    Attitude,
    CameraCalibration,
    NavCameraFrame,
    RerankCandidate,
    RerankResult,
    TileId,
)
from c3_matcher.errors import InsufficientInliersError, MatcherBackboneError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features, RawMatches
from c3_matcher.pipeline import QUERY_ROTATIONS_DEG, PipelineSettings
from c3_matcher.prepared import InputRule, PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.ransac import OpenCvRansacFilter
from c3_matcher.testing import (
    ScriptedCandidate,
    ScriptedRig,
    SequenceRansacFilter,
    scripted_pipeline,
)
from c3_matcher.tiles import BytesTileHandle

S = ScriptedCandidate
QUERY = 254  # FakeInferenceRuntime records the query frame (mark 255) as 254
REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "demo"


ON = PipelineSettings(rotation_search=True)
LEVEL = Attitude.from_degrees(0.0, 0.0, 0.0)


# -- settings -------------------------------------------------------------------------------
def test_rotation_search_is_off_by_default_and_reaches_the_pipeline(tmp_path):
    assert not PipelineSettings().rotation_search
    assert not load_settings(env={}).matcher.rotation_search
    assert not PipelineSettings.from_settings(load_settings(env={}).matcher).rotation_search
    toml = tmp_path / "c3.toml"
    toml.write_text("[matcher]\nrotation_search = true\n")
    assert PipelineSettings.from_settings(load_settings(toml, env={}).matcher).rotation_search
    env = {"C3_MATCHER_MATCHER__ROTATION_SEARCH": "true"}
    assert load_settings(env=env).matcher.rotation_search


# -- control flow (scripted doubles) --------------------------------------------------------
def test_off_by_default_one_query_extraction_and_records_unchanged(fdr, logs):
    rig = ScriptedRig([S(120), S(80)], fdr, PipelineSettings())
    result = rig.match()
    assert rig.query_extractions == 1
    assert result.diagnostics["rotation_search"] is False
    assert result.diagnostics["rotation_deg"] == [0, 0]
    (done,) = fdr.of_kind("matcher.frame_done")
    assert "rotation_search" not in done
    assert all("rotation_deg" not in row for row in done["per_candidate"])


def test_on_with_attitude_one_query_extraction(fdr, logs):
    rig = ScriptedRig([S(120), S(80)], fdr, ON, attitude=LEVEL)
    result = rig.match()
    assert rig.query_extractions == 1
    assert result.diagnostics["rotation_search"] is False
    assert "rotation_search" not in fdr.of_kind("matcher.frame_done")[0]


def test_on_without_attitude_four_query_extractions_one_per_tile(fdr, logs):
    rig = ScriptedRig([S(120), S(80), S(70)], fdr, ON)
    result = rig.match()
    assert rig.query_extractions == len(QUERY_ROTATIONS_DEG) == 4
    assert sorted(c for c in rig.inference.calls if c != QUERY) == [0, 1, 2]  # tiles: once
    assert len(rig.lightglue.calls) == 3 * 4 and len(rig.ransac.calls) == 3 * 4
    assert result.diagnostics["rotation_search"] is True
    assert result.diagnostics["rotation_deg"] == [0, 0, 0]  # a full tie keeps the first turn
    timings = result.diagnostics["timings_ms"]
    assert {"query_preprocess", "query_extract", "total"} <= set(timings)
    (done,) = fdr.of_kind("matcher.frame_done")  # exactly one terminal record
    assert done["rotation_search"] is True and done["rotations_deg"] == [0, 90, 180, 270]
    assert [row["rotation_deg"] for row in done["per_candidate"]] == [0, 0, 0]


def test_each_candidate_keeps_the_turn_ranked_best_by_the_pipeline_rule(fdr, logs):
    # candidate 0: turns 90 and 180 tie on inliers, 180 has the lower residual -> 180;
    # candidate 1: 270 has the most inliers whatever its residual -> 270
    outcomes = [(50, 2.0), (80, 1.5), (80, 1.0), (10, 0.1), (5, 0.1), (6, 0.1), (7, 1), (99, 3)]
    rig = ScriptedRig([S(), S()], fdr, ON, ransac=SequenceRansacFilter(outcomes))
    result = rig.match()
    assert [c.inlier_count for c in result.per_candidate] == [99, 80]
    assert [c.per_candidate_residual_px for c in result.per_candidate] == [3.0, 1.0]
    assert result.diagnostics["input_index"] == [1, 0]
    assert result.diagnostics["rotation_deg"] == [270, 180]
    (done,) = fdr.of_kind("matcher.frame_done")
    assert [r["rotation_deg"] for r in done["per_candidate"]] == [270, 180]
    assert done["best_inlier_count"] == 99


def test_query_failure_under_rotation_search_is_one_terminal_backbone_error(fdr, logs):
    rig = ScriptedRig([S(100)], fdr, ON)
    rig.inference.script = [S()] * 255
    rig.inference.script[QUERY] = S(fail_extract=True)
    with pytest.raises(MatcherBackboneError) as info:
        rig.match()
    assert info.value.phase == "query_extract"
    assert [r["phase"] for r in fdr.of_kind("matcher.backbone_error")] == ["query_extract"]
    assert fdr.of_kind("matcher.frame_done") == []
    assert fdr.of_kind("matcher.insufficient_inliers") == []


def test_candidate_failure_under_rotation_search_drops_it_once(fdr, logs):
    rig = ScriptedRig([S(100, fail_match=True), S(90), S(30)], fdr, ON)
    result = rig.match()
    assert result.candidates_dropped == 1
    assert [r["phase"] for r in fdr.of_kind("matcher.backbone_error")] == ["lightglue_match"]
    assert [c.inlier_count for c in result.per_candidate] == [90, 30]


def test_insufficient_under_rotation_search_records_the_turns(fdr, logs):
    rig = ScriptedRig([S(20), S(10)], fdr, ON)
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (record,) = fdr.of_kind("matcher.insufficient_inliers")
    assert record["rotation_search"] is True
    assert [r["rotation_deg"] for r in record["per_candidate"]] == [0, 0]
    assert fdr.of_kind("matcher.frame_done") == []


class _DotBackend:
    """Keypoints at the dots of a synthetic image (channel 0 > 40); a dot's descriptor is its
    value and the direction of its tail (channel 1 > 100 in a 4-neighbour): a turned image
    matches only when the tails point the same way, as a real descriptor is not
    rotation-invariant."""

    label = "dots"
    extract_phase = "dots_extract"
    match_phase = "dots_match"
    input_rule = InputRule(max_long_side=64, multiple=16)

    def __init__(self) -> None:
        self.extractions = 0

    def extract(self, image: PreparedImage) -> Features:
        self.extractions += 1
        img = image.image.astype(np.int32)
        ys, xs = np.nonzero(img[:, :, 0] > 40)
        keypoints, descriptors = [], []
        for x, y in zip(xs, ys, strict=True):
            for code, (dx, dy) in enumerate(((1, 0), (0, -1), (-1, 0), (0, 1))):
                tx, ty = x + dx, y + dy
                if 0 <= tx < img.shape[1] and 0 <= ty < img.shape[0] and img[ty, tx, 1] > 100:
                    keypoints.append((x, y))
                    descriptors.append((img[y, x, 0], code))
        n = len(keypoints)
        return Features(
            np.asarray(keypoints, np.float32).reshape(n, 2),
            np.asarray(descriptors, np.float32).reshape(n, 2),
            np.ones(n, np.float32),
            image.engine_size,
        )

    def match(self, query: Features, tile: Features) -> RawMatches:
        pairs = [
            (i, j)
            for i, dq in enumerate(query.descriptors)
            for j, dt in enumerate(tile.descriptors)
            if np.array_equal(dq, dt)
        ]
        m = np.asarray(pairs, np.int64).reshape(-1, 2)
        return RawMatches(m, np.ones(len(m), np.float32))

    def provenance(self) -> Mapping[str, Any]:
        return {"provider": "none"}


DOTS = [(8, 9), (20, 12), (40, 7), (50, 22), (13, 30), (33, 28), (44, 44), (10, 50), (26, 52)]


def _dot_image(shift: tuple[int, int], values: Sequence[int]) -> NDArray[np.uint8]:
    """64x64, background 10 (not nodata), dot i at DOTS[i] + shift (channel 0 = values[i]),
    its tail one pixel to the right (channel 1 = 200)."""
    image = np.full((64, 64, 3), 10, np.uint8)
    for (x, y), v in zip(DOTS, values, strict=True):
        image[y + shift[1], x + shift[0], 0] = v
        image[y + shift[1], x + shift[0] + 1, 1] = 200
    return image


def _png(image: NDArray[np.uint8]) -> BytesTileHandle:
    ok, buf = cv2.imencode(".png", image[:, :, ::-1])
    assert ok
    return BytesTileHandle(buf.tobytes(), "dots")


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_the_matching_turn_wins_and_points_come_back_in_the_frame_as_given(fdr, logs, k):
    values = [60 + 15 * i for i in range(len(DOTS))]
    base = _dot_image((0, 0), values)
    tile = _dot_image((4, 3), values)  # the true tile: the same dots, shifted
    distractor = _dot_image((2, 2), [v + 5 for v in values])  # no descriptor in common
    frame_image = np.ascontiguousarray(np.rot90(base, k))  # the frame, turned, no attitude
    frame = NavCameraFrame(uuid.UUID(int=9), frame_image, 1)
    calibration = CameraCalibration.pinhole(64, 64, focal_px=64.0)
    rerank = RerankResult(
        frame.frame_id,
        tuple(
            RerankCandidate(TileId(18, 47.0 + i / 1000, 8.5), 1.0 - i / 10, _png(t), 0.3)
            for i, t in enumerate((distractor, tile))
        ),
    )
    settings = PipelineSettings(min_inliers_threshold=6, geometric_prior=False)
    ransac = OpenCvRansacFilter()
    off = _DotBackend()
    if k == 0:  # the frame is already as the tile: no search needed
        assert scripted_pipeline(off, ransac, fdr, settings).match(frame, rerank, calibration)
    else:
        with pytest.raises(InsufficientInliersError):
            scripted_pipeline(off, ransac, fdr, settings).match(frame, rerank, calibration)
    assert off.extractions == 1 + 2

    on = _DotBackend()
    searching = PipelineSettings(
        min_inliers_threshold=6, geometric_prior=False, rotation_search=True
    )
    result = scripted_pipeline(on, ransac, fdr, searching).match(frame, rerank, calibration)
    assert on.extractions == 4 + 2
    assert result.diagnostics["input_index"] == [1]  # the true tile; the distractor dropped
    assert result.diagnostics["rotation_deg"] == [(360 - 90 * k) % 360]
    best = result.per_candidate[0]
    assert best.inlier_count == len(DOTS)
    # each inlier: the frame pixel AS GIVEN (turned) holds the dot the tile pixel holds
    xq, yq, xt, yt = np.rint(best.inlier_correspondences).astype(int).T
    assert np.allclose(best.inlier_correspondences, np.rint(best.inlier_correspondences), atol=1e-3)
    assert np.array_equal(frame_image[yq, xq, 0], tile[yt, xt, 0])
    assert set(frame_image[yq, xq, 0].tolist()) == set(values)


# -- real path: the demo frame through the real xfeat engines --------------------------------
def _demo() -> tuple[dict[str, Any], CameraCalibration, NDArray[np.uint8]]:
    from c3_matcher import load_calibration

    meta = json.loads((DEMO / "demo.json").read_text())
    calibration = load_calibration(DEMO / "calibration.json")
    image = cv2.cvtColor(cv2.imread(str(DEMO / "frame.jpg")), cv2.COLOR_BGR2RGB)
    return meta, calibration, np.asarray(image, np.uint8)


def _demo_attitude(meta: Mapping[str, Any]) -> Attitude:
    att = meta["attitude_deg"]
    return Attitude.from_degrees(att["roll"], att["pitch"], att["yaw"])


def _rectified_demo() -> NDArray[np.uint8]:
    """The demo frame as a nadir north-up camera at the tiles' GSD would see it (rectified with
    its own attitude and height, full resolution): a heading error of 0 on real imagery."""
    meta, calibration, image = _demo()
    frame = NavCameraFrame(
        uuid.uuid4(), image, 1, _demo_attitude(meta), height_above_ground_m=meta["height_m"]
    )
    pre = FramePreprocessor(InputRule(max_long_side=4096, multiple=1), border_erode_px=0)
    return pre.prepare_query(frame, calibration, meta["tile_gsd_m"]).image


def _demo_rerank(frame_id: uuid.UUID, meta: Mapping[str, Any]) -> RerankResult:
    from c3_matcher import MmapTileHandle

    return RerankResult(
        frame_id,
        tuple(
            RerankCandidate(
                TileId(*t["tile_id"]),
                1.0 - 0.1 * i,
                MmapTileHandle(DEMO / t["file"]),
                gsd_m_per_px=meta["tile_gsd_m"],
            )
            for i, t in enumerate(meta["tiles"])
        ),
    )


class _Root:
    """A real composition root (strategy xfeat) with ``rotation_search`` and an in-memory FDR."""

    def __init__(self, engine_dir: Path, rotation_search: bool, tile_cache_size: int = 16):
        from c3_matcher.compose import build_default_helpers, compose_root
        from c3_matcher.config import C3Settings

        settings = C3Settings(
            matcher={
                "strategy": "xfeat",
                "rotation_search": rotation_search,
                "tile_cache_size": tile_cache_size,
            },
            engines={"directory": engine_dir},
        )
        self.fdr = InMemoryFdr()
        helpers = {**build_default_helpers(settings), "c13_fdr": self.fdr}
        self.root = compose_root(settings, helpers, configure_logs=False)

    def match(
        self, image: NDArray[np.uint8], attitude: Attitude | None = None, **frame_kw: Any
    ) -> Any:
        meta, calibration, _ = _demo()
        h, w = image.shape[:2]
        if attitude is None and "calibration" not in frame_kw:  # a nadir pinhole of the image
            calibration = CameraCalibration.pinhole(w, h, focal_px=float(max(w, h)))
        calibration = frame_kw.pop("calibration", calibration)
        frame = NavCameraFrame(uuid.uuid4(), image, 1, attitude, **frame_kw)
        return self.root.matcher.match(frame, _demo_rerank(frame.frame_id, meta), calibration)

    def close(self) -> None:
        self.root.close()


@pytest.fixture(scope="module")
def xfeat_roots(engine_dir: Path) -> Iterator[dict[bool, _Root]]:
    roots = {flag: _Root(engine_dir, flag) for flag in (False, True)}
    try:
        yield roots
    finally:
        for root in roots.values():
            root.close()


def test_real_demo_frame_turned_90_deg_without_attitude_found_only_with_the_search(xfeat_roots):
    """Measured (xfeat, this machine): the rectified demo frame as given: true tile (tile_b)
    354 inliers; turned 90 deg, search off: insufficient (best 12); search on: tile_b, 342
    inliers, kept turn 270 (which undoes the 90)."""
    meta, _, _ = _demo()
    true_index = next(i for i, t in enumerate(meta["tiles"]) if t["true"])
    rectified = _rectified_demo()
    reference = xfeat_roots[False].match(rectified)  # as rectified: the reference geometry
    assert reference.diagnostics["input_index"][0] == true_index
    reference_inliers = reference.per_candidate[0].inlier_count
    assert reference_inliers >= 150
    h_ref = reference.diagnostics["homographies"][0]  # rectified px -> tile px

    turned = np.ascontiguousarray(np.rot90(rectified, 1))
    try:
        off = xfeat_roots[False].match(turned)
        off_true = off.diagnostics["input_index"][0] == true_index
        off_inliers = off.per_candidate[0].inlier_count
        assert not off_true or off_inliers < reference_inliers // 3
    except InsufficientInliersError:
        pass  # measured: best 12 < 60

    on = xfeat_roots[True].match(turned)
    assert on.diagnostics["input_index"][0] == true_index
    assert on.diagnostics["rotation_deg"][0] == 270
    best = on.per_candidate[0]
    assert best.inlier_count >= reference_inliers // 2
    # the inliers' query points are in px of the TURNED frame as given: turned (x', y') is
    # rectified (w - 1 - y', x'); the reference homography then lands on the tile points
    w = rectified.shape[1]
    xq, yq = best.inlier_correspondences[:, 0], best.inlier_correspondences[:, 1]
    rect = np.stack([w - 1 - yq, xq, np.ones_like(xq)], axis=1).astype(np.float64) @ h_ref.T
    error = np.linalg.norm(rect[:, :2] / rect[:, 2:3] - best.inlier_correspondences[:, 2:4], axis=1)
    assert float(np.median(error)) < 3.0
    done = xfeat_roots[True].fdr.of_kind("matcher.frame_done")[-1]
    assert done["rotation_search"] is True and done["per_candidate"][0]["rotation_deg"] == 270


def test_real_demo_frame_with_attitude_is_untouched_by_the_search(xfeat_roots):
    meta, calibration, image = _demo()
    attitude = _demo_attitude(meta)
    kw = {"calibration": calibration, "height_above_ground_m": meta["height_m"]}
    off = xfeat_roots[False].match(image, attitude, **dict(kw))
    on = xfeat_roots[True].match(image, attitude, **dict(kw))
    assert on.diagnostics["rotation_search"] is False
    assert on.diagnostics["input_index"] == off.diagnostics["input_index"]
    assert [c.inlier_count for c in on.per_candidate] == [c.inlier_count for c in off.per_candidate]


# -- the cost (docs/accuracy.md): python core/tests/test_rotation_search.py ----------
def _cost(runs: int = 5) -> None:
    import os

    engine_dir = Path(os.environ.get("C3_MATCHER_ENGINES__DIRECTORY", REPO / ".engines"))
    meta, calibration, image = _demo()
    turned = np.ascontiguousarray(np.rot90(_rectified_demo(), 1))
    cases = {
        "demo frame, attitude given": (image, _demo_attitude(meta), calibration),
        "demo frame, attitude=None": (image, None, calibration),
        "rectified demo frame turned 90 deg, attitude=None": (turned, None, None),
    }
    for cache in (16, 0):
        print(f"tile_cache_size={cache} (0: every tile extracted every frame)")
        for name, (img, att, cal) in cases.items():
            row = []
            for flag in (False, True):
                root = _Root(engine_dir, flag, cache)
                kw: dict[str, Any] = {"height_above_ground_m": meta["height_m"]} if cal else {}
                if cal is not None:
                    kw["calibration"] = cal
                times = []
                try:
                    for i in range(runs + 1):
                        start = time.perf_counter()
                        outcome = "insufficient"
                        try:
                            r = root.match(img, att, **dict(kw))
                            tile = meta["tiles"][r.diagnostics["input_index"][0]]["file"]
                            outcome = f"{tile} {r.per_candidate[0].inlier_count}"
                        except InsufficientInliersError:
                            pass
                        if i:  # the first frame warms up (and fills the tile cache)
                            times.append((time.perf_counter() - start) * 1e3)
                finally:
                    root.close()
                row.append((statistics.median(times), outcome))
            (t_off, o_off), (t_on, o_on) = row
            print(
                f"  {name}: off {t_off:.0f} ms ({o_off}), on {t_on:.0f} ms ({o_on}), "
                f"ratio {t_on / t_off:.2f}"
            )


if __name__ == "__main__":
    _cost(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
