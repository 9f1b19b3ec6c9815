"""Candidates of two zooms in one frame, end to end with the real engines: each is matched
against the query scaled to its own GSD, so a distractor of another zoom neither moves the
true tile's query off its scale nor lets the geometric prior refuse the true tile on scale.

The store is built from the shipped GeoTIFF at zooms 14 and 15 (``tiles build``); the frame is
the first of the shipped ``naip_demo`` flight, with its attitude and height."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
GEOTIFF = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
DISTRACTOR = "47.010,-99.180"  # a tile ~3 km from the true one, at the zoom given


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("zooms") / "multi.mbtiles"
    built = run_cli("tiles", "build", GEOTIFF, path, "--zoom", "14", "--zoom", "15", cwd=REPO)
    assert built.returncode == 0, built.stderr[-2000:]
    return path


def _frame() -> dict[str, Any]:
    first = (FLIGHT / "frames.jsonl").read_text().splitlines()[0]
    return dict(json.loads(first))


def _match(store: Path, engine_dir: Path, fdr: Path, distractor_zoom: int) -> dict[str, Any]:
    """``c3-matcher match`` of the flight's first frame against its true zoom-15 tile and a
    distractor at ``distractor_zoom``: the printed result and the FDR's ``frame_done``."""
    frame = _frame()
    true_tile = ",".join(map(str, frame["candidates"][0]["tile_id"]))
    proc = run_cli(
        *("match", "--query", FLIGHT / frame["image"]),
        *("--calibration", FLIGHT / "calibration.json"),
        *("--attitude", ",".join(map(str, frame["attitude_deg"]))),
        *("--height", str(frame["height_m"]), "--store", store),
        *("--tile-id", true_tile, "--tile-id", f"{distractor_zoom},{DISTRACTOR}"),
        *("--fdr", fdr, "--no-correspondences"),
        cwd=REPO,
        engine_dir=engine_dir,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr[-2000:]
    records = [json.loads(line) for line in fdr.read_text().splitlines()]
    (done,) = [r["payload"] for r in records if r["kind"] == "matcher.frame_done"]
    return {"result": json.loads(proc.stdout), "frame_done": done}


def _centre_on_tile(done: dict[str, Any]) -> Any:
    """Where the frame's UNDISTORTED centre lands on the best tile (px), through the record's
    ``best_homography @ query_rectification``."""
    w, h = json.loads((FLIGHT / "calibration.json").read_text())["image_size"]
    composed = np.asarray(done["best_homography"]) @ np.asarray(done["query_rectification"])
    x, y, s = composed @ np.array([w / 2, h / 2, 1.0])
    return np.array([x / s, y / s])


def test_a_distractor_of_another_zoom_leaves_the_true_tile_its_fix(
    store: Path, engine_dir: Path, tmp_path: Path
) -> None:
    one_zoom = _match(store, engine_dir, tmp_path / "one.jsonl", 15)
    mixed = _match(store, engine_dir, tmp_path / "mixed.jsonl", 14)
    true_tile = _frame()["candidates"][0]["tile_id"]
    for run in (one_zoom, mixed):
        best = run["result"]["per_candidate"][0]
        assert best["tile_id"] == true_tile and best["tile_index"] == 0
        assert run["frame_done"]["best_tile_id"] == true_tile
    inliers = [r["result"]["per_candidate"][0]["inlier_count"] for r in (one_zoom, mixed)]
    assert inliers[0] >= 300 and abs(inliers[1] - inliers[0]) <= 0.05 * inliers[0], inliers
    centres = [_centre_on_tile(r["frame_done"]) for r in (one_zoom, mixed)]
    assert np.linalg.norm(centres[1] - centres[0]) <= 1.0, centres
