"""Each candidate of ``match``'s JSON says where its tile px lie on the map: ``tile_size_px``,
``tile_origin_world_px`` (WORLD px of TILE px (0, 0), the top-left pixel's centre) and
``world_px_per_tile_px``, so that a step downstream places the inliers' tile points without
re-deriving how a store window is rounded onto its zoom's pixel grid.

The real path: a frame of the shipped demo flight against its store, the true window's id moved
off the zoom's grid (a third of a px east, 0.4 px north), by the OpenCV strategy (no engines);
and the README's demo frame against its ``--tile`` images, centred exactly on their ids."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher import camera as cam
from c3_matcher.dto import TileId
from c3_matcher.georef import tile_px_to_lonlat
from c3_matcher.tiles import decode_image
from c3_matcher.tilestore import MBTilesStore
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px, world_px_to_lonlat

from .demo_match import DEMO, DEMO_MATCH, FLIGHT, WINDOW, run_match

OFF_GRID = (1 / 3, -0.4)  # WORLD px the id is moved off the true window's centre


def _off_grid_id() -> TileId:
    """Frame 0's true window's id, moved :data:`OFF_GRID` off the zoom's pixel grid."""
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    zoom, lat, lon = next(c["tile_id"] for c in record["candidates"] if c["is_true"])
    centre = lonlat_to_world_px([[lon, lat]], zoom)[0] + OFF_GRID
    lon, lat = world_px_to_lonlat(centre[None, :], zoom)[0]
    return TileId(zoom, float(lat), float(lon))


@pytest.fixture(scope="module")
def store_match(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Frame 0 of the demo flight matched against its off-grid true window (with inliers)."""
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    tile_id = _off_grid_id()
    argv = [
        *("match", "--query", str(FLIGHT / record["image"])),
        *("--store", str(FLIGHT / "tiles.mbtiles"), "--window", str(WINDOW)),
        *("--tile-id", f"{tile_id.zoom},{tile_id.lat!r},{tile_id.lon!r}"),
        *("--calibration", str(FLIGHT / "calibration.json"), "--height", str(record["height_m"])),
        *("--attitude", ",".join(map(str, record["attitude_deg"])), "--strategy", "sift_magsac"),
        *("--fdr", str(tmp_path_factory.mktemp("fdr") / "fdr.jsonl")),
    ]
    proc = run_match(argv=argv)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return dict(json.loads(proc.stdout))


def _placed(entry: dict[str, Any], tile_px: np.ndarray) -> np.ndarray:
    """(lon, lat) of ``tile_px`` placed by the candidate's own JSON fields alone."""
    origin = np.asarray(entry["tile_origin_world_px"], np.float64)
    world = origin + entry["world_px_per_tile_px"] * np.asarray(tile_px, np.float64)
    return world_px_to_lonlat(world, entry["tile_id"][0])


def test_a_store_window_off_the_grid_is_placed_where_its_pixels_came_from(
    store_match: dict[str, Any],
) -> None:
    (best,) = store_match["per_candidate"]
    tile_id = TileId(*best["tile_id"])
    assert best["tile_size_px"] == [WINDOW, WINDOW] and best["world_px_per_tile_px"] == 1.0
    origin = np.asarray(best["tile_origin_world_px"])
    centre = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0]
    snapped = origin + (WINDOW - 1) / 2 - centre  # the window's centre off the id's
    assert np.allclose(snapped, -np.asarray(OFF_GRID), rtol=0, atol=1e-6)  # the id rounded
    corr = np.asarray(best["inlier_correspondences"], np.float64)
    corners = [[0, 0], [WINDOW - 1, 0], [0, WINDOW - 1], [WINDOW - 1, WINDOW - 1]]
    tile_px = np.concatenate([corr[:, 2:4], corners])
    expected = tile_px_to_lonlat(tile_id, (WINDOW, WINDOW), tile_px)
    assert np.allclose(_placed(best, tile_px), expected, rtol=0, atol=1e-10)
    # the pixels the matcher was served are the store's at that origin, pixel for pixel
    with MBTilesStore(FLIGHT / "tiles.mbtiles") as store:
        served = store.handle(tile_id, WINDOW).decode()
        x0, y0 = (int(v) for v in origin - 0.5)
        assert np.array_equal(served, _stitched(store, tile_id.zoom, x0, y0))


def test_a_store_windows_placement_puts_the_frame_centre_where_the_result_does(
    store_match: dict[str, Any],
) -> None:
    """The principal point through ``best_homography`` (UNDISTORTED query px -> tile px) and
    the best candidate's placement lands on the result's ``centre_lat`` / ``centre_lon``."""
    (best,) = store_match["per_candidate"]
    k = json.loads((FLIGHT / "calibration.json").read_text())["K"]
    tile_px = cam.apply_homography(np.asarray(store_match["best_homography"]), [[k[0][2], k[1][2]]])
    lon, lat = _placed(best, tile_px)[0]
    assert (lat, lon) == pytest.approx((store_match["centre_lat"], store_match["centre_lon"]))


def test_every_kept_store_window_is_placed_not_only_the_best(tmp_path: Path) -> None:
    """Frame 0 against its three recorded windows: the OpenCV strategy keeps two (the true one
    and a neighbour); each kept entry has its own window's size and origin (the best's size once
    stood in for the others')."""
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    ids = [
        a for c in record["candidates"] for a in ("--tile-id", ",".join(map(repr, c["tile_id"])))
    ]
    argv = [
        *("match", "--query", str(FLIGHT / record["image"])),
        *("--store", str(FLIGHT / "tiles.mbtiles"), "--window", str(WINDOW), *ids),
        *("--calibration", str(FLIGHT / "calibration.json"), "--height", str(record["height_m"])),
        *("--attitude", ",".join(map(str, record["attitude_deg"])), "--strategy", "sift_magsac"),
        *("--no-correspondences", "--fdr", str(tmp_path / "fdr.jsonl")),
    ]
    proc = run_match(argv=argv)
    assert proc.returncode == 0, proc.stderr[-2000:]
    kept = json.loads(proc.stdout)["per_candidate"]
    assert len(kept) >= 2, kept  # the case this is about: a kept candidate after the best
    corners = np.array([[0, 0], [WINDOW - 1, 0], [0, WINDOW - 1], [WINDOW - 1, WINDOW - 1]])
    for entry in kept:
        tile_id = TileId(*entry["tile_id"])
        assert entry["tile_size_px"] == [WINDOW, WINDOW] and entry["world_px_per_tile_px"] == 1.0
        centre = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0]
        off = np.asarray(entry["tile_origin_world_px"]) + (WINDOW - 1) / 2 - centre
        assert np.all(np.abs(off) <= 0.5), off  # its own window, rounded onto the grid
        expected = tile_px_to_lonlat(tile_id, (WINDOW, WINDOW), corners)
        assert np.allclose(_placed(entry, corners), expected, rtol=0, atol=1e-10)


def test_a_tile_image_is_placed_centred_exactly_on_its_id_at_its_gsd(tmp_path: Path) -> None:
    demo = json.loads((DEMO / "demo.json").read_text())
    ids = [a for t in demo["tiles"] for a in ("--tile-id", ",".join(map(str, t["tile_id"])))]
    fdr = ("--fdr", str(tmp_path / "fdr.jsonl"))  # its own: tests run side by side
    proc = run_match(*ids, *fdr, argv=[a for a in DEMO_MATCH if a != "--no-correspondences"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    for entry in out["per_candidate"]:
        tile_id, size = TileId(*entry["tile_id"]), tuple(entry["tile_size_px"])
        assert size == (512, 512)
        assert entry["world_px_per_tile_px"] == pytest.approx(
            demo["tile_gsd_m"] / tile_id.web_mercator_gsd_m(), rel=1e-12
        )
        tile_px = np.asarray(entry["inlier_correspondences"], np.float64)[:, 2:4]
        tile_px = np.concatenate([tile_px, [[(size[0] - 1) / 2, (size[1] - 1) / 2]]])
        expected = tile_px_to_lonlat(tile_id, size, tile_px, demo["tile_gsd_m"])
        assert np.allclose(_placed(entry, tile_px), expected, rtol=0, atol=1e-10)
        assert np.allclose(expected[-1], [tile_id.lon, tile_id.lat], rtol=0, atol=1e-10)


def test_a_tile_without_an_id_is_placed_nowhere(tmp_path: Path) -> None:
    proc = run_match("--fdr", str(tmp_path / "fdr.jsonl"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    for entry in json.loads(proc.stdout)["per_candidate"]:
        assert entry["tile_id"] is None and entry["tile_size_px"] == [512, 512]
        assert entry["tile_origin_world_px"] is None and entry["world_px_per_tile_px"] is None


def _stitched(store: MBTilesStore, zoom: int, x0: int, y0: int) -> np.ndarray:
    """The ``WINDOW`` px square of the store's WORLD px whose top-left pixel is (x0, y0), read
    from its stored tiles here (every one of them present)."""
    out = np.zeros((WINDOW, WINDOW, 3), np.uint8)
    for ty in range(y0 // TILE_PX, (y0 + WINDOW - 1) // TILE_PX + 1):
        for tx in range(x0 // TILE_PX, (x0 + WINDOW - 1) // TILE_PX + 1):
            blob = store.tile_bytes(zoom, tx, ty)
            assert blob is not None
            tile = decode_image(blob, f"{zoom}/{tx}/{ty}")
            ox, oy = tx * TILE_PX - x0, ty * TILE_PX - y0
            sx, sy = max(0, -ox), max(0, -oy)
            ex, ey = min(TILE_PX, WINDOW - ox), min(TILE_PX, WINDOW - oy)
            out[oy + sy : oy + ey, ox + sx : ox + ex] = tile[sy:ey, sx:ex]
    return out


def test_the_library_serializer_places_each_kept_candidate_by_its_input_position() -> None:
    """``result_to_json`` (the Python API's serializer) places every kept candidate by its own
    input position's size and GSD: here the best came from input 2 (a 300 px image at 0.5 m/px)
    and the other kept one from input 0 (a store window, GSD None)."""
    import uuid

    from c3_matcher.dto import CandidateMatchSet, MatchResult
    from c3_matcher.georef import candidate_placement
    from c3_matcher.serialize import result_to_json

    ids = (TileId(17, 47.0, 8.0), TileId(17, 47.001, 8.001))
    corr = np.zeros((30, 4), np.float32)
    kept = tuple(CandidateMatchSet(i, 30, corr, 5, 1.0) for i in ids)
    result = MatchResult(uuid.UUID(int=1), kept, 0, 1.0, 0, "test", 3, 1, {"input_index": [2, 0]})
    sizes, gsds = [(448, 448), (0, 0), (300, 200)], [None, None, 0.5]
    out = result_to_json(result, tile_sizes=sizes, tile_gsds=gsds)
    best, other = out["per_candidate"]
    assert best["tile_index"] == 2 and other["tile_index"] == 0
    assert {k: best[k] for k in candidate_placement(ids[0], (300, 200), 0.5)} == (
        candidate_placement(ids[0], (300, 200), 0.5)
    )
    assert best["tile_size_px"] == [300, 200] and best["world_px_per_tile_px"] != 1.0
    assert {k: other[k] for k in candidate_placement(ids[1], (448, 448))} == (
        candidate_placement(ids[1], (448, 448))
    )
    assert "tile_origin_world_px" not in result_to_json(result)["per_candidate"][0]
