"""The footprint is the ground the frame sees, on the real path: a frame rendered over a real
orthophoto so far nose up that its top edge looks above the horizon, matched by the real engine
with ``c3-matcher match``, has its footprint ahead of the vehicle, within the off-nadir cone
(the maps themselves: ``core/tests/test_georef_horizon.py``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from c3_matcher import camera as cam
from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.georef import tile_px_to_lonlat
from c3_matcher.testing.cli import run_cli
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.sim.render import cut_tile, render_nav_frame

REPO = Path(__file__).resolve().parents[1]
ORTHO = REPO / "data" / "imagery" / "open_orthophotos" / "5b90f92da0d7280005fab355_4310.tif"
TILE_ID = TileId(21, 14.5955, 120.982)
HEIGHT_M = 30.0
M_PER_DEG = 111_320.0
CALIBRATION = CameraCalibration(
    np.array([[420.0, 0.0, 319.5], [0.0, 420.0, 239.5], [0.0, 0.0, 1.0]]),
    np.zeros(5),
    (640, 480),
    camera_to_body=cam.DEFAULT_BODY_FROM_CAMERA,
)


def test_match_puts_the_footprint_of_a_frame_seeing_the_sky_ahead_of_the_vehicle(
    engine_dir: Path, tmp_path: Path
) -> None:
    """The real path: a frame rendered over a real orthophoto 62 deg nose up (its top edge
    1.7 deg above the horizon) matched by the real engine against a tile of the ground it sees.
    The match is right; its footprint lay up to a kilometre behind the vehicle."""
    photo = load_orthophoto(ORTHO)
    assert photo.gsd_m is not None
    calibration = CALIBRATION
    attitude = (0.0, 62.0, 30.0)
    nadir_px = (700.0, 1500.0)
    frame = render_nav_frame(
        photo.rgb, photo.gsd_m, nadir_px, HEIGHT_M, Attitude.from_degrees(*attitude), calibration
    )
    look = frame.undistorted_to_ortho([[319.5, 400.0]])[0]
    tile = cut_tile(
        photo.rgb, (round(look[0]) - 511, round(look[1]) - 511), (1024, 1024), photo.gsd_m
    )
    paths = {name: tmp_path / f"{name}.png" for name in ("query", "tile")}
    cv2.imwrite(str(paths["query"]), frame.image[:, :, ::-1])
    cv2.imwrite(str(paths["tile"]), tile.image[:, :, ::-1])
    (tmp_path / "cal.json").write_text(
        json.dumps({"K": calibration.K.tolist(), "distortion": [0.0] * 5, "image_size": [640, 480]})
    )
    proc = run_cli(
        *("match", "--query", paths["query"], "--tile", paths["tile"]),
        *("--tile-gsd", repr(photo.gsd_m), "--tile-id", ",".join(map(str, TILE_ID.as_list()))),
        *("--calibration", tmp_path / "cal.json", "--no-correspondences"),
        *("--attitude", ",".join(map(str, attitude)), "--height", str(HEIGHT_M)),
        cwd=tmp_path,
        engine_dir=engine_dir,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    ring = np.asarray(out["footprint"], np.float64)
    nadir_tile = tile.ortho_to_tile([nadir_px])
    (lon_n, lat_n) = tile_px_to_lonlat(TILE_ID, tile.size, nadir_tile, photo.gsd_m)[0]
    north = (ring[:, 1] - lat_n) * M_PER_DEG
    east = (ring[:, 0] - lon_n) * M_PER_DEG * math.cos(math.radians(lat_n))
    along = north * math.cos(math.radians(30.0)) + east * math.sin(math.radians(30.0))
    assert along.min() > 0.0
    assert np.hypot(north, east).max() < HEIGHT_M * math.tan(math.radians(76.0))
