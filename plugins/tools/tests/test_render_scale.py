"""``dataset render`` over a store far larger than the flight: it holds the flight's part of the
store, not the store. It stitched every tile of the store's finest zoom into one image (about
200 bytes of memory per store pixel with the distractor search's masks: a 40,000-tile z18 store
ran out of memory); the distractors it draws over the whole store stay the same draws."""

from __future__ import annotations

import json
import shutil
import sqlite3
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.handles import stitch
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.flight import render_flight
from c3_matcher_tools.dataset.flight_candidates import distractor_origins
from c3_matcher_tools.dataset.flight_scene import Footprint, read_scene
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.sim.render import pick_distractor_tiles

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
DEMO_STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
FAR_COLUMNS = 120
"""How far east (tiles) of the demo store's tiles one more of its tiles is stored: the store's
tiles then span 127 x 5 tiles at zoom 15, a 125 MB image where the flight needs a few tiles."""


def _store_with_a_far_tile(tmp_path: Path) -> Path:
    """The demo store (35 tiles at zoom 15) with a copy of one of its tiles stored
    :data:`FAR_COLUMNS` columns east of its easternmost one, its sha256 with it."""
    store = shutil.copyfile(DEMO_STORE, tmp_path / "wide.mbtiles")
    with sqlite3.connect(store) as db:
        z, x, row, blob = db.execute(
            "SELECT zoom_level, tile_column, tile_row, tile_data FROM tiles "
            "ORDER BY tile_column DESC, tile_row LIMIT 1"
        ).fetchone()
        (digest,) = db.execute(
            "SELECT sha256 FROM c3_tile_digest WHERE zoom_level=? AND tile_column=? AND tile_row=?",
            (z, x, row),
        ).fetchone()
        db.execute("INSERT INTO tiles VALUES (?, ?, ?, ?)", (z, x + FAR_COLUMNS, row, blob))
        db.execute(
            "INSERT INTO c3_tile_digest VALUES (?, ?, ?, ?)", (z, x + FAR_COLUMNS, row, digest)
        )
    return store


def _render_peak(store: Path, out: Path) -> int:
    """Render three frames over ``store`` into ``out``; the peak of memory allocated meanwhile
    (bytes)."""
    spec = FlightSpec(NAIP_2020, store, n_frames=3, absent_share=1 / 3, seed=1)
    tracemalloc.start()
    try:
        render_flight(spec, out, name="scale")
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_store_far_wider_than_the_flight_is_rendered_in_the_flights_memory(
    tmp_path: Path,
) -> None:
    near = _render_peak(shutil.copyfile(DEMO_STORE, tmp_path / "near.mbtiles"), tmp_path / "a")
    far = _render_peak(_store_with_a_far_tile(tmp_path), tmp_path / "b")
    coverage_image = (7 + FAR_COLUMNS) * 5 * 256 * 256 * 3
    assert far - near < coverage_image / 16, (near, far)
    # the same frames, over the same true tiles (the distractors may differ: windows reaching
    # east of the demo's tiles into the gap hold little enough nodata to be drawn)
    assert _true_tiles(tmp_path / "a") == _true_tiles(tmp_path / "b")
    for frame in sorted((tmp_path / "a" / "frames").iterdir()):
        assert frame.read_bytes() == (tmp_path / "b" / "frames" / frame.name).read_bytes()


def _true_tiles(dataset: Path) -> list[list[object]]:
    """Each frame's true tile id, in frame order ([] for a frame without one)."""
    frames = [json.loads(line) for line in (dataset / "frames.jsonl").read_text().splitlines()]
    return [[c["tile_id"] for c in f["candidates"] if c["is_true"]] for f in frames]


@pytest.mark.parametrize(
    ("size", "grid_px", "distance_m", "nodata"),
    [(448, 32, 350.0, 0.35), (256, 64, 100.0, 0.6), (224, 32, 800.0, 0.1)],
)
def test_distractors_are_the_draws_over_the_whole_coverage(
    size: int, grid_px: int, distance_m: float, nodata: float
) -> None:
    """The windows drawn from the store a window at a time are those drawn over the whole
    coverage stitched into one image, for footprints inside, across and beyond its edges,
    present (clear of the centre) and absent (clear of the footprint) alike."""
    spec = FlightSpec(
        NAIP_2020,
        DEMO_STORE,
        candidate_size_px=size,
        grid_px=grid_px,
        min_distractor_distance_m=distance_m,
        max_distractor_nodata=nodata,
    )
    rng = np.random.default_rng(7)
    compared = 0
    with MBTilesStore(DEMO_STORE) as store:
        scene = read_scene(spec, store)
        cov = scene.cov
        whole = stitch(store, cov.zoom, cov.origin, cov.size, "demo")
        for k in range(40):
            absent = bool(k % 2)
            centre = rng.uniform(-300, 300, 2) + rng.uniform(0, 1, 2) * cov.size
            world = centre + rng.uniform(-150, 150, (4, 2)) + cov.origin
            origin = (int(rng.integers(0, 10**6)), int(rng.integers(0, 10**6)))
            footprint = Footprint(world, world.mean(axis=0), origin)
            fp = (
                world - cov.origin
                if absent
                else np.repeat(footprint.centre[None] - cov.origin, 3, 0)
            )
            expected: object
            try:
                tiles = pick_distractor_tiles(
                    whole,
                    fp,
                    (size, size),
                    3 if absent else 2,
                    np.random.default_rng([spec.seed, int(absent), *origin]),
                    scene.m_per_px,
                    margin_px=8,
                    min_distance_px=distance_m / scene.m_per_px,
                    max_nodata_fraction=0.5 if absent else nodata,
                    stride_px=grid_px,
                )
                expected = [
                    (cov.origin[0] + t.offset_px[0], cov.origin[1] + t.offset_px[1]) for t in tiles
                ]
            except InvalidInputError as exc:
                expected = exc.reason
            try:
                got: object = distractor_origins(spec, scene, k, footprint, absent)
            except InvalidInputError as exc:
                assert isinstance(expected, str) and expected in exc.reason
                continue
            assert got == expected
            compared += 1
    assert compared >= 20
