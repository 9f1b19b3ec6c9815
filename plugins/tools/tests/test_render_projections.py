"""``dataset render`` on projected grids whose scale is not 1 where the flight is, and at the
antimeridian. The shipped NAIP sheet (934 x 723 px of 5 m) relabelled: UTM 14N (its own grid),
WGS 84 / PDC Mercator at 17 S (EPSG:3832, scale 1.045) and Antarctic polar stereographic at
77.7 S (EPSG:3031, scale 0.984). The frames took one grid unit for one ground metre, so on the
last two they showed the ground as from another height than the recorded one, and the dataset's
truth and the recorded pose (nadir, attitude, height) disagreed by metres."""

from __future__ import annotations

import json
import math
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod, Transformer

from c3_matcher import load_calibration
from c3_matcher.camera import rotation_world_from_camera
from c3_matcher.dto import Attitude, TileId
from c3_matcher.georef import tile_px_to_lonlat
from c3_matcher_tools.dataset.flight import render_flight
from c3_matcher_tools.dataset.flight_scene import grid_units_per_m
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.geodesy import WGS84_E2, ground_gsd_m
from c3_matcher_tools.sim import load_orthophoto
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.geotiff import projected_keys, write_geotiff
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.geo import read_geotiff_grid

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
GEOD = Geod(ellps="WGS84")
PDC_E_AT_180 = 6378137.0 * math.radians(30.0)
"""EPSG:3832's easting of the 180th meridian (its central meridian is 150 E)."""
PDC_N = -1906000.0
"""The northing of the relabelled sheets' top edge in EPSG:3832 (about 17 S)."""


def _relabelled(path: Path, epsg: int, top_left: tuple[float, float]) -> Path:
    """The NAIP sheet's pixels at ``path``, 5 units a pixel, in CRS ``epsg`` from ``top_left``."""
    rgb = load_orthophoto(NAIP_2020).rgb
    return write_geotiff(path, rgb, scale=(5.0, 5.0), top_left=top_left, keys=projected_keys(epsg))


def _truth_from_pose_m(dataset: Path) -> list[tuple[float, float]]:
    """Per frame with a true tile: (how far the camera looks from its nadir, how far the
    dataset's truth puts the principal point from where the recorded nadir, attitude and
    height make it look), metres on the WGS84 ellipsoid."""
    calibration = load_calibration(dataset / "calibration.json")
    size = json.loads((dataset / "dataset.json").read_text())["candidate_size_px"]
    k = calibration.K
    out = []
    for line in (dataset / "frames.jsonl").read_text().splitlines():
        frame = json.loads(line)
        pose, true = frame["pose"], [c for c in frame["candidates"] if c["is_true"]]
        h = np.linalg.inv(np.array(true[0]["h_tile_to_undistorted"]))
        q = h @ [k[0, 2], k[1, 2], 1.0]
        lon, lat = tile_px_to_lonlat(TileId(*true[0]["tile_id"]), (size, size), [q[:2] / q[2]])[0]
        attitude = Attitude.from_degrees(*frame["attitude_deg"])
        north, east, down = rotation_world_from_camera(attitude, calibration) @ [0.0, 0.0, 1.0]
        off_n, off_e = frame["height_m"] * north / down, frame["height_m"] * east / down
        offset = math.hypot(off_n, off_e)
        azimuth = math.degrees(math.atan2(off_e, off_n))
        look_lon, look_lat, _ = GEOD.fwd(pose["nadir_lon"], pose["nadir_lat"], azimuth, offset)
        out.append((offset, GEOD.inv(look_lon, look_lat, lon, lat)[2]))
    return out


@pytest.mark.parametrize(
    ("epsg", "top_left", "zoom"),
    [
        (26914, (485899.0, 5209246.0), 15),
        (3832, (2223900.0, -1908339.0), 15),
        (3031, (3e5, -1.3e6), 14),
    ],
    ids=["utm-14n", "pdc-mercator-17s", "polar-stereographic-77s"],
)
def test_truth_agrees_with_the_recorded_pose_where_the_grid_scale_is_not_one(
    tmp_path: Path, epsg: int, top_left: tuple[float, float], zoom: int
) -> None:
    """Up to 6.7 m apart (PDC Mercator) and 2.7 m (polar stereographic) at a 155 m look offset.
    What stays is the truth homography's fit over its window (``gt_fit_max_residual_px``): 3 cm
    for UTM; a window of about 1 km at 77.7 S (zoom 14), where the grid turns 4 deg over 2 km."""
    tif = _relabelled(tmp_path / "sheet.tif", epsg, top_left)
    store = tmp_path / "sheet.mbtiles"
    build_mbtiles(tif, store, zoom=zoom, tile_format="jpg")
    spec = FlightSpec(tif, store, n_frames=8, height_m=500.0, orbit_radius_m=250.0, absent_share=0)
    agreement = _truth_from_pose_m(render_flight(spec, tmp_path / "flight"))
    assert max(offset for offset, _ in agreement) > 140.0  # tilted: the camera looks far off
    assert max(error for _, error in agreement) < 0.2, agreement


def test_the_ground_gsd_is_the_grid_scale_over_the_projections_scale_factor() -> None:
    """``tiles build`` reports a source's m/px from it: PDC Mercator at 17 S (its scale the
    ellipsoid's Mercator factor), UTM on its central meridian (0.9996)."""
    lat = -17.0
    s2 = math.sin(math.radians(lat)) ** 2
    mercator = math.sqrt(1 - WGS84_E2 * s2) / math.cos(math.radians(lat))
    gsd = ground_gsd_m(5.0, 5.0, lat, lon_deg=170.0, geographic=False, epsg=3832)
    assert gsd == pytest.approx(5.0 / mercator, rel=1e-7)
    assert gsd == pytest.approx(4.783, abs=0.001)
    utm = ground_gsd_m(5.0, 5.0, 47.0, lon_deg=-99.0, geographic=False, epsg=32614)
    assert utm == pytest.approx(5.0 / 0.9996, rel=1e-7)


def test_a_grid_at_the_antimeridian_measures_its_scale_there(tmp_path: Path) -> None:
    """A half-pixel step either way of 180 deg is one pixel on the ground, not 360 deg of
    longitude (it read 3.83e+07 m wide and refused the grid as one of equal degrees)."""
    tif = _relabelled(tmp_path / "x180.tif", 3832, (PDC_E_AT_180 - 934 * 5.0 / 2, PDC_N))
    grid = read_geotiff_grid(tif)
    centre_n = PDC_N - 723 * 5.0 / 2
    ue, un = grid_units_per_m(grid, (PDC_E_AT_180, centre_n))
    lat = Transformer.from_crs(3832, 4326, always_xy=True).transform(PDC_E_AT_180, centre_n)[1]
    phi = math.radians(lat)
    k = math.sqrt(1 - WGS84_E2 * math.sin(phi) ** 2) / math.cos(phi)
    assert (ue, un) == pytest.approx((k, k), rel=1e-5)


@pytest.fixture(scope="module")
def west_of_180(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store built from the sheet in EPSG:3832 ending 10 m west of 180 deg at 17 S."""
    where = tmp_path_factory.mktemp("west")
    tif = _relabelled(where / "west.tif", 3832, (PDC_E_AT_180 - 934 * 5.0 - 10.0, PDC_N))
    store = where / "west.mbtiles"
    build_mbtiles(tif, store, tile_format="jpg")
    return store


def test_a_store_across_the_antimeridian_is_refused_naming_it(
    tmp_path: Path, west_of_180: Path
) -> None:
    """Two of its tiles copied to columns 0 and 1 (east of 180 deg), frames from the sheet it
    was built from: its tiles' bounding box spanned the whole world (an internal error,
    MemoryError: unable to allocate 24 GiB)."""
    store = shutil.copyfile(west_of_180, tmp_path / "both_sides.mbtiles")
    with sqlite3.connect(store) as db:
        z, row, blob = db.execute(
            "SELECT zoom_level, tile_row, tile_data FROM tiles ORDER BY tile_column DESC LIMIT 1"
        ).fetchone()
        for column in (0, 1):
            db.execute("INSERT INTO tiles VALUES (?, ?, ?, ?)", (z, column, row, blob))
    frames = west_of_180.with_suffix(".tif")
    r = run_cli("dataset", "render", frames, store, tmp_path / "out", cwd=tmp_path, timeout=300)
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "antimeridian" in r.stderr and "both_sides.mbtiles" in r.stderr
    assert not (tmp_path / "out").exists()


def test_a_flight_across_the_antimeridian_is_refused_naming_it(
    tmp_path: Path, west_of_180: Path
) -> None:
    """Frames over a sheet centred on 180 deg, flown round a point 40 m west of it: the
    footprints cross it (refused as larger than a candidate, 8.4 million WORLD px wide)."""
    store = shutil.copyfile(west_of_180, tmp_path / "west.mbtiles")
    centre_n = PDC_N - 723 * 5.0 / 2
    lon, lat = Transformer.from_crs(3832, 4326, always_xy=True).transform(
        PDC_E_AT_180 - 40.0, centre_n
    )
    with sqlite3.connect(store) as db:
        db.execute("UPDATE metadata SET value=? WHERE name='center'", (f"{lon},{lat},15",))
    frames = _relabelled(tmp_path / "x180.tif", 3832, (PDC_E_AT_180 - 934 * 5.0 / 2, PDC_N))
    r = run_cli(
        "dataset", "render", frames, store, tmp_path / "out",
        "--frames", "4", "--height", "120", "--radius", "100",
        cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "antimeridian" in r.stderr and "frame 0" in r.stderr
    assert not (tmp_path / "out").exists()
