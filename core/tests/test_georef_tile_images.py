"""A ``--tile`` image and a store window are read differently: a tile store's window lies on its
zoom's pixel grid (its corner the id's centre rounded onto it), an image the user gives is
centred exactly on its ``--tile-id``, whatever its GSD, the zoom's own included. And the
footprint is a counter-clockwise ring in lon/lat (RFC 7946's exterior ring) in every output,
``match`` JSON and ``results.jsonl`` as ``flight.geojson``, whichever way the map turns it.

The ``match`` test runs the real engines on the shipped demo flight: frame 0 against its true
tile's store window, and against that window moved by half a pixel with its exact centre as
``--tile-id`` (a WMS crop, say)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher.dto import CameraCalibration, TileId
from c3_matcher.georef import footprint_lonlat, haversine_m, tile_px_to_lonlat
from c3_matcher.testing.cli import run_cli
from c3_matcher.tilestore.geo import lonlat_to_world_px, world_px_to_lonlat
from c3_matcher.tilestore.handles import mosaic_origin
from c3_matcher.tilestore.mbtiles import MBTilesStore

REPO = Path(__file__).resolve().parents[2]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
ZOOM = 15
SIZE = (448, 320)


def _off_grid_id() -> TileId:
    """A zoom-15 id whose centre is a quarter and three tenths of a WORLD px off the grid."""
    (x, y) = lonlat_to_world_px([[-99.1516, 47.0271]], ZOOM)[0]
    lon, lat = world_px_to_lonlat([[np.floor(x) + 0.25, np.floor(y) + 0.7]], ZOOM)[0]
    return TileId(ZOOM, float(lat), float(lon))


def _twice_area(ring: Any) -> float:
    """Twice the signed shoelace area of a closed lon/lat ring (> 0: counter-clockwise)."""
    d = np.asarray(ring, np.float64) - np.asarray(ring, np.float64)[0]
    return float(np.sum(d[:-1, 0] * d[1:, 1] - d[1:, 0] * d[:-1, 1]))


@pytest.mark.parametrize("gsd_factor", [1.0, 0.5])
def test_an_image_with_a_gsd_is_centred_exactly_on_its_id(gsd_factor: float) -> None:
    """Its centre pixel maps to the id's lon/lat, the zoom's own GSD (factor 1) included: once
    an image of that exact GSD was snapped onto the zoom's grid, its centre moved up to half a
    pixel (here 0.25 and 0.3 px: 1.3 m)."""
    tile_id = _off_grid_id()
    w, h = SIZE
    gsd = tile_id.web_mercator_gsd_m() * gsd_factor
    lon, lat = tile_px_to_lonlat(tile_id, SIZE, [[(w - 1) / 2, (h - 1) / 2]], gsd)[0]
    assert haversine_m([[lon, lat]], [[tile_id.lon, tile_id.lat]])[0] < 1e-6
    assert abs(lon - tile_id.lon) < 1e-12 and abs(lat - tile_id.lat) < 1e-12


def test_a_store_window_still_lies_on_the_zooms_grid() -> None:
    """Without a GSD the image is a store window: its pixel (0, 0) is the WORLD px whose corner
    :func:`mosaic_origin` gives, so its centre is off the id's by the id's own offset."""
    tile_id = _off_grid_id()
    w, h = SIZE
    ox, oy = mosaic_origin(tile_id, w)[0], mosaic_origin(tile_id, h)[1]
    lonlat = tile_px_to_lonlat(tile_id, SIZE, [[0.0, 0.0]])
    world = lonlat_to_world_px(lonlat, ZOOM)[0]
    assert np.allclose(world, [ox + 0.5, oy + 0.5], atol=1e-6)
    (cx, cy) = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], ZOOM)[0]
    middle = tile_px_to_lonlat(tile_id, SIZE, [[(w - 1) / 2, (h - 1) / 2]])
    centre = lonlat_to_world_px(middle, ZOOM)
    assert np.allclose(centre[0] - [cx, cy], [-0.25, 0.3], atol=1e-6)


@pytest.mark.parametrize("mirror", [False, True])
def test_the_footprint_winds_counter_clockwise(mirror: bool) -> None:
    """Through a north-up map the image boundary comes clockwise in lon/lat, through a mirroring
    one (a camera seen in a mirror) the other way: the ring is counter-clockwise either way, and
    closed, around the same centre."""
    calibration = CameraCalibration.pinhole(320, 240, focal_px=300.0)
    flip = np.diag([-1.0, 1.0, 1.0]) if mirror else np.eye(3)
    to_tile = np.array([[1.0, 0.0, 64.0], [0.0, 1.0, 40.0], [0.0, 0.0, 1.0]]) @ flip
    if mirror:
        to_tile[0, 2] += 320.0
    centre, ring = footprint_lonlat(to_tile, _off_grid_id(), SIZE, calibration)
    assert _twice_area(ring) > 0
    assert np.array_equal(ring[0], ring[-1])
    assert abs(np.mean(ring[:-1, 0]) - centre[0]) < 1e-4


def _frame_0_match(tmp_path: Path, engine_dir: Path, *candidate: str) -> dict[str, Any]:
    frame = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    proc = run_cli(
        *("match", "--query", FLIGHT / frame["image"]),
        *("--calibration", FLIGHT / "calibration.json", "--no-correspondences"),
        *("--attitude", ",".join(map(str, frame["attitude_deg"])), "--height", frame["height_m"]),
        *candidate,
        cwd=tmp_path,
        engine_dir=engine_dir,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return dict(json.loads(proc.stdout))


def _half_shifted_window(tmp_path: Path, tile_id: TileId, size: int) -> tuple[Path, str]:
    """The store's window on ``tile_id`` moved half a pixel right and down (resampled), and its
    exact centre as a ``--tile-id``: pixel i now shows WORLD px ``origin + i`` (a pixel corner,
    no pixel centre of the zoom's grid)."""
    with MBTilesStore(FLIGHT / "tiles.mbtiles") as store:
        window = store.handle(tile_id, size).decode()
    shift = np.float32([[1, 0, 0.5], [0, 1, 0.5]])
    moved = cv2.warpAffine(window, shift, (size, size), borderMode=cv2.BORDER_REFLECT)
    path = tmp_path / "moved.png"
    cv2.imwrite(str(path), moved[:, :, ::-1])
    ox, oy = mosaic_origin(tile_id, size)
    lon, lat = world_px_to_lonlat([[ox + (size - 1) / 2, oy + (size - 1) / 2]], tile_id.zoom)[0]
    return path, f"{tile_id.zoom},{float(lat)!r},{float(lon)!r}"


def test_match_centres_a_tile_image_on_its_id_and_winds_its_footprint(engine_dir, tmp_path):
    """Frame 0 against its true tile's store window, then against that window moved half a
    pixel with its exact centre as id, no ``--tile-gsd``: the same place within a few cm
    (measured 4 cm; 2.3 m when the image was snapped onto the grid), and both footprints
    counter-clockwise."""
    frame = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    true_id = TileId(*frame["candidates"][0]["tile_id"])
    assert frame["candidates"][0]["is_true"]
    store = _frame_0_match(
        tmp_path,
        engine_dir,
        *("--store", str(FLIGHT / "tiles.mbtiles"), "--window", "448"),
        *("--tile-id", ",".join(map(str, frame["candidates"][0]["tile_id"]))),
    )
    path, moved_id = _half_shifted_window(tmp_path, true_id, 448)
    image = _frame_0_match(tmp_path, engine_dir, "--tile", str(path), "--tile-id", moved_id)
    a, b = ([r["centre_lon"], r["centre_lat"]] for r in (store, image))
    assert haversine_m([a], [b])[0] < 0.15
    for result in (store, image):
        assert _twice_area(result["footprint"]) > 0
