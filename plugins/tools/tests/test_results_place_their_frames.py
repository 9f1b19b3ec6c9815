"""``results.jsonl`` holds what a step downstream needs to use a frame's fix without the
dataset's code: each line's ``captured_at_ns`` (the frame's, as its FDR records say it), and
each kept candidate's placement on the map (``tile_size_px``, ``tile_origin_world_px``, the
WORLD px of TILE px (0, 0), and ``world_px_per_tile_px``), the store window's rounding onto its
zoom's grid included. The real path: two frames of the shipped demo flight replayed by the OpenCV
strategy (no engines), the first's candidates' ids moved off the zoom's pixel grid."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher import camera as cam
from c3_matcher.config import C3Settings
from c3_matcher.dto import TileId
from c3_matcher.fdr import read_fdr_log
from c3_matcher.georef import tile_px_to_lonlat
from c3_matcher.tilestore import MBTilesStore
from c3_matcher.tilestore.geo import lonlat_to_world_px, world_px_to_lonlat
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import FlightOptions, fly
from c3_matcher_tools.run.results_file import write_results

from .conftest import Record, SmallFlight, edit_frame_record

OFF_GRID = (0.3, -0.45)  # WORLD px the first frame's candidate ids are moved
KIND = "matcher.frame_done"


def _off_grid(record: Record) -> None:
    for candidate in record["candidates"]:
        zoom, lat, lon = candidate["tile_id"]
        centre = lonlat_to_world_px([[lon, lat]], zoom)[0] + OFF_GRID
        lon, lat = world_px_to_lonlat(centre[None, :], zoom)[0]
        candidate["tile_id"] = [zoom, float(lat), float(lon)]


def _replayed(small_flight: SmallFlight, tmp_path: Path) -> tuple[Path, Path, list[dict[str, Any]]]:
    """The two-frame flight (the first off the grid), the run's directory and its results.jsonl
    read back."""
    from c3_matcher.compose import build_plugin_host

    root = small_flight("placed")
    edit_frame_record(root, 1, _off_grid)
    flight, out = load_dataset(root), tmp_path / "out"
    out.mkdir()
    run = fly(
        C3Settings(),
        "sift_magsac",
        flight,
        out,
        plugin_host=build_plugin_host(),
        options=FlightOptions(flight.frames),
    )
    lines = write_results(out / "results.jsonl", run.outcomes).read_text().splitlines()
    return root, out, [json.loads(line) for line in lines]


def test_each_result_line_is_timed_and_places_its_candidates_on_the_map(
    small_flight: SmallFlight, tmp_path: Path
) -> None:
    root, out, rows = _replayed(small_flight, tmp_path)
    frames = [json.loads(x) for x in (root / "frames.jsonl").read_text().splitlines()]
    records = list(read_fdr_log(out / "fdr.jsonl"))
    done = {r["payload"]["frame_id"]: r["payload"] for r in records if r["kind"] == KIND}
    assert [r["captured_at_ns"] for r in rows] == [f["captured_at_ns"] for f in frames]
    assert [r["captured_at_ns"] for r in rows] == [0, 2_000_000_000]
    matched = [r for r in rows if r["status"] == "ok"]
    assert matched and matched[0]["index"] == 0  # the off-grid frame among them
    size = json.loads((root / "dataset.json").read_text())["candidate_size_px"]
    k = json.loads((root / "calibration.json").read_text())["K"]
    with MBTilesStore(root / "tiles.mbtiles") as store:
        for row in matched:
            assert done[row["frame_id"]]["captured_at_ns"] == row["captured_at_ns"]
            for entry in row["result"]["per_candidate"]:
                _check_placed(entry, store, size, OFF_GRID if row["index"] == 0 else (0.0, 0.0))
            best = row["result"]["per_candidate"][0]
            centre = cam.apply_homography(
                np.asarray(row["result"]["best_homography"]), [[k[0][2], k[1][2]]]
            )
            placed = world_px_to_lonlat(best["tile_origin_world_px"] + centre, best["tile_id"][0])
            lon, lat = placed[0]
            assert np.allclose([lat, lon], [row["est_lat"], row["est_lon"]], rtol=0, atol=1e-10)


def _check_placed(
    entry: dict[str, Any], store: MBTilesStore, size: int, off_grid: tuple[float, float]
) -> None:
    """The candidate's placement is where its window's pixels came from (the window's centre
    ``off_grid`` from its id's, rounded onto the grid) and places its tile px as the georeference
    does."""
    tile_id = TileId(*entry["tile_id"])
    assert entry["tile_size_px"] == [size, size] and entry["world_px_per_tile_px"] == 1.0
    origin = np.asarray(entry["tile_origin_world_px"])
    assert np.array_equal(origin, np.asarray(store.handle(tile_id, size).origin_world_px) + 0.5)
    centre = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0]
    assert np.allclose(origin + (size - 1) / 2 - centre, -np.asarray(off_grid), rtol=0, atol=1e-6)
    tile_px = np.asarray(entry["inlier_correspondences"], np.float64)[:, 2:4]
    placed = world_px_to_lonlat(origin + tile_px, tile_id.zoom)
    expected = tile_px_to_lonlat(tile_id, (size, size), tile_px)
    assert np.allclose(placed, expected, rtol=0, atol=1e-10)
