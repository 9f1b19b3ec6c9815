"""``tiles build`` at the edges of the web-mercator world, on the shipped NAIP sheet's pixels
rewritten under other grids: an orthophoto across 180 deg is tiled on both sides (each tile
checked against GDAL's own reprojection), one holding a pole is refused before planning, rows
beyond 85.0511 deg are left out and said, a UTM grid used beyond its zone (as national grids are)
is read while a wrong CRS is still refused, one across the equator is read in either UTM zone
of it, and a rotated grid is called what it is."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import rasterio
import tifffile
from numpy.typing import NDArray
from pyproj import Transformer
from rasterio.transform import Affine
from rasterio.warp import Resampling, reproject

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import MERCATOR_MAX_LAT
from c3_matcher_tools.geotiff import GEO_KEY_DIRECTORY
from c3_matcher_tools.testing.geotiff import projected_keys
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.geo import TM_REACH_M
from c3_matcher_tools.tilestore.projection import Projection

from .conftest import stored_tiles

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
READERS = pytest.mark.parametrize("use_rasterio", [True, False], ids=["rasterio", "tifffile"])
WORLD_M = 2 * math.pi * 6378137.0  # web-mercator world width, metres
MODEL_TRANSFORMATION = 34264


def naip_as(tmp_path: Path, name: str, crs: str, transform: Affine) -> Path:
    """The NAIP sheet's RGB pixels (934 x 723) under ``crs`` and ``transform``."""
    with rasterio.open(NAIP_2020) as ds:
        rgb = ds.read([1, 2, 3])
    path = tmp_path / f"{name}.tif"
    profile = dict(driver="GTiff", width=rgb.shape[2], height=rgb.shape[1], count=3)
    with rasterio.open(path, "w", **profile, dtype="uint8", crs=crs, transform=transform) as out:
        out.write(rgb)
    return path


def at(e0: float, n0: float, sx: float = 5.0, sy: float | None = None) -> Affine:
    """A north-up transform, top-left corner (e0, n0), pixels ``sx`` x ``sy``."""
    return Affine(sx, 0.0, e0, 0.0, -(sx if sy is None else sy), n0)


def stored(store: Path) -> dict[tuple[int, int, int], NDArray[np.uint8]]:
    """Every tile of ``store`` as RGB, by (zoom, x, y) (XYZ rows)."""
    return {k: np.ascontiguousarray(bgr[:, :, ::-1]) for k, bgr in stored_tiles(store).items()}


def gdal_tile(tif: Path, z: int, x: int, y: int) -> NDArray[np.uint8]:
    """GDAL's own reprojection of ``tif`` into tile (z, x, y)'s EPSG:3857 bounds (RGB)."""
    n = 1 << z
    west, east = x / n * WORLD_M - WORLD_M / 2, (x + 1) / n * WORLD_M - WORLD_M / 2
    north, south = WORLD_M / 2 - y / n * WORLD_M, WORLD_M / 2 - (y + 1) / n * WORLD_M
    dst = np.zeros((3, 256, 256), np.uint8)
    with rasterio.open(tif) as src:
        reproject(
            rasterio.band(src, [1, 2, 3]),
            dst,
            dst_transform=Affine((east - west) / 256, 0.0, west, 0.0, (south - north) / 256, north),
            dst_crs="EPSG:3857",
            resampling=Resampling.bilinear,
        )
    return np.ascontiguousarray(dst.transpose(1, 2, 0))


def shift_px(ours: NDArray[np.uint8], gdal: NDArray[np.uint8]) -> float:
    """How far (tile px) our tile is shifted from GDAL's, over the pixels both hold."""
    both = (ours.sum(axis=2) > 0) & (gdal.sum(axis=2) > 0)
    a = cv2.cvtColor(ours, cv2.COLOR_RGB2GRAY).astype(np.float32) * both
    b = cv2.cvtColor(gdal, cv2.COLOR_RGB2GRAY).astype(np.float32) * both
    (dx, dy), _ = cv2.phaseCorrelate(a, b)
    return float(math.hypot(dx, dy))


def assert_placed_as_gdal_does(tif: Path, store: Path) -> dict[tuple[int, int, int], Any]:
    """Each stored tile holds what GDAL puts there: shifted from it by under 0.25 tile px where
    both hold enough pixels to tell (0.1 px over the median tile)."""
    tiles = stored(store)
    assert tiles
    shifts = []
    for (z, x, y), ours in tiles.items():
        gdal = gdal_tile(tif, z, x, y)
        assert (gdal.sum(axis=2) > 0).any(), f"tile {z}/{x}/{y} holds no data for GDAL"
        if ((ours.sum(axis=2) > 0) & (gdal.sum(axis=2) > 0)).sum() >= 4000:
            shifts.append(shift_px(ours, gdal))
            assert shifts[-1] < 0.25, f"tile {z}/{x}/{y}"
    assert shifts and float(np.median(shifts)) < 0.1, shifts
    return tiles


def at_most(limit: int) -> Any:
    """A progress callback that fails the build when it plans more than ``limit`` tiles."""

    def progress(_done: int, total: int) -> None:
        assert total <= limit, f"{total:,} tiles planned"

    return progress


ACROSS_180 = {  # 4.67 x 3.6 km straddling 180 deg
    "utm60s": ("EPSG:32760", 817_000.0, 8_100_000.0),  # Fiji, zone 60 (east edge at 180)
    "utm1s": ("EPSG:32701", 178_200.0, 8_100_000.0),  # zone 1 (west edge at 180)
    "pdc_mercator": ("EPSG:3832", 3_336_500.0, -1_906_000.0),  # PDC Mercator, 17 S
    "antarctic_stereo": ("EPSG:3031", -2_000.0, -1_300_000.0),  # 78.3 S
}


@READERS
@pytest.mark.parametrize("case", list(ACROSS_180))
def test_an_orthophoto_across_180_deg_is_tiled_on_both_sides_as_gdal_places_it(
    tmp_path: Path, case: str, use_rasterio: bool
) -> None:
    crs, e0, n0 = ACROSS_180[case]
    tif = naip_as(tmp_path, case, crs, at(e0, n0))
    report = build_mbtiles(
        tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio, progress=at_most(60)
    )
    assert report.candidates <= 60
    tiles = assert_placed_as_gdal_does(tif, report.path)
    z = report.zoom
    n = 1 << z
    columns = {x for _z, x, _y in tiles}
    assert {n - 1, 0} <= columns and columns <= {n - 3, n - 2, n - 1, 0, 1, 2}, columns
    rows = {y for _z, _x, y in tiles}
    for y in rows:  # every tile GDAL finds data in, beside 180 deg, is stored
        for x in (n - 3, n - 2, n - 1, 0, 1, 2):
            covered = (gdal_tile(tif, z, x, y).sum(axis=2) > 0).mean()
            assert covered < 0.01 or (z, x, y) in tiles, (x, y, covered)


@pytest.mark.parametrize(
    ("crs", "e0", "n0", "pole"),
    [
        ("EPSG:3413", -2_000.0, 2_000.0, "North Pole"),
        ("EPSG:3031", -2_000.0, 2_000.0, "South Pole"),
    ],
)
def test_an_orthophoto_holding_a_pole_is_refused_before_planning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], crs: str, e0: float, n0: float, pole: str
) -> None:
    from c3_matcher.cli import main

    tif = naip_as(tmp_path, "pole", crs, at(e0, n0))
    with pytest.raises(InvalidInputError, match=rf"holds the {pole}.*web-mercator"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", zoom=15, progress=at_most(0))
    assert not (tmp_path / "o.mbtiles").exists()
    capsys.readouterr()
    assert main(["tiles", "build", str(tif), str(tmp_path / "o.mbtiles"), "--zoom", "15"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(tif) in err and pole in err, err
    assert not (tmp_path / "o.mbtiles").exists()


@READERS
def test_rows_beyond_85_deg_are_left_out_and_the_summary_says_how_much(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], use_rasterio: bool
) -> None:
    from c3_matcher.cli import main

    tif = naip_as(tmp_path, "north", "EPSG:4326", at(10.0, 85.07, 0.0002, 0.00005))
    report = build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    tiles = stored(report.path)
    assert tiles and all(0 <= y < (1 << z) for z, _x, y in tiles)
    assert min(y for _z, _x, y in tiles) == 0  # the world's top row holds the part within it
    beyond = np.mean(85.07 - (np.arange(723) + 0.5) * 0.00005 > MERCATOR_MAX_LAT) * 100
    assert report.beyond_world_pct == pytest.approx(beyond, abs=0.5)
    assert 50 < report.beyond_world_pct < 54
    for (z, x, y), ours in tiles.items():
        if y == 0:
            assert shift_px(ours, gdal_tile(tif, z, x, y)) < 0.25
    capsys.readouterr()
    reader = "rasterio" if use_rasterio else "tifffile"
    argv = ["tiles", "build", str(tif), str(tmp_path / "c.mbtiles")]
    assert main([*argv, "--reader", reader]) == 0
    out = capsys.readouterr().out
    assert f"{report.beyond_world_pct:.0f} % of the orthophoto" in out, out
    assert "beyond the web-mercator world" in out, out


def test_an_orthophoto_wholly_beyond_85_deg_is_refused_naming_the_limit(tmp_path: Path) -> None:
    tif = naip_as(tmp_path, "far_north", "EPSG:4326", at(10.0, 86.0, 0.0002, 0.00005))
    with pytest.raises(InvalidInputError, match=r"north of 85\.0511.*web-mercator world"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", progress=at_most(0))
    assert not (tmp_path / "o.mbtiles").exists()


BEYOND_ZONE = {  # national grids used beyond their UTM zone
    "bornholm_25832": ("EPSG:25832", 868_000.0, 6_118_000.0),  # Denmark, 14.8 E
    "kirkenes_25833": ("EPSG:25833", 1_070_000.0, 7_780_000.0),  # Norway, 29.7 E
    "kirkenes_32633": ("EPSG:32633", 1_070_000.0, 7_780_000.0),  # hand-written UTM
    "utvaer_25833": ("EPSG:25833", -66_000.0, 6_814_000.0),  # Norway, 4.5 E
    "utvaer_32633": ("EPSG:32633", -66_000.0, 6_814_000.0),
}


@pytest.mark.parametrize("case", list(BEYOND_ZONE))
def test_a_national_utm_grid_beyond_its_zone_is_tiled_where_gdal_places_it(
    tmp_path: Path, case: str
) -> None:
    crs, e0, n0 = BEYOND_ZONE[case]
    tif = naip_as(tmp_path, case, crs, at(e0, n0))
    report = build_mbtiles(tif, tmp_path / "o.mbtiles")
    assert report.tiles > 0
    assert_placed_as_gdal_does(tif, report.path)


ON_THE_EQUATOR = {  # 4.67 x 3.6 km across the equator, in either zone of it (Gabon, 9.5 E)
    "north_zone_32632": ("EPSG:32632", 553_000.0, 1_800.0),  # northings down to -1,815 m
    "south_zone_32732": ("EPSG:32732", 553_000.0, 10_001_800.0),  # up to 10,001,800 m
}


@READERS
@pytest.mark.parametrize("case", list(ON_THE_EQUATOR))
def test_an_orthophoto_across_the_equator_is_tiled_in_either_utm_zone_where_gdal_places_it(
    tmp_path: Path, case: str, use_rasterio: bool
) -> None:
    crs, e0, n0 = ON_THE_EQUATOR[case]
    tif = naip_as(tmp_path, case, crs, at(e0, n0))
    report = build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    tiles = assert_placed_as_gdal_does(tif, report.path)
    n = 1 << report.zoom
    assert {y for _z, _x, y in tiles} >= {n // 2 - 1, n // 2}  # tiles both sides of the equator


@pytest.mark.parametrize(
    ("crs", "e0", "n0", "said"),
    [
        ("EPSG:32632", 553_000.0, -TM_REACH_M - 10_000, "do not fit EPSG:32632"),
        ("EPSG:32732", 553_000.0, 1e7 + TM_REACH_M + 10_000, "do not fit EPSG:32732"),
        ("EPSG:32633", 500_000 + TM_REACH_M + 10_000, 7_780_000.0, "do not fit EPSG:32633"),
        ("EPSG:32633", 500_000 - TM_REACH_M - 10_000, 7_780_000.0, "do not fit EPSG:32633"),
        ("EPSG:32633", 33_070_000.0, 7_780_000.0, "do not fit EPSG:32633"),  # zone-prefixed
        ("EPSG:32633", 15.0, 69.9, "do not fit EPSG:32633.*look like degrees"),
        ("EPSG:25833", 500_000 + TM_REACH_M + 10_000, 7_780_000.0, "EPSG:25833's area of use"),
        ("EPSG:25832", 868_000.0, 1_118_000.0, "EPSG:25832's area of use"),  # 10 N, not Europe
        ("EPSG:25832", 14.8, 55.06, "EPSG:25832's area of use"),  # degrees
    ],
)
def test_a_grid_beyond_the_transverse_mercator_reach_or_the_wrong_place_is_still_refused(
    tmp_path: Path, crs: str, e0: float, n0: float, said: str
) -> None:
    scale = 5.0 if e0 > 1_000 or e0 < 0 else 5e-5
    tif = naip_as(tmp_path, "wrong", crs, at(e0, n0, scale))
    for use_rasterio in (True, False):
        with pytest.raises(InvalidInputError, match=rf"{said}.*is the CRS right"):
            build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    assert not (tmp_path / "o.mbtiles").exists()


def test_the_utm_maths_agrees_with_pyproj_to_a_millimetre_out_to_its_reach() -> None:
    assert TM_REACH_M == 1_000_000.0  # the README's 1,000 km
    utm = Projection("utm", zone=33)
    to_lonlat = Transformer.from_crs(32633, 4326, always_xy=True)
    to_utm = Transformer.from_crs(4326, 32633, always_xy=True)
    north = np.linspace(0.0, 9_300_000.0, 94)
    for e in (500_000 - TM_REACH_M, 500_000 + TM_REACH_M):
        east = np.full_like(north, e)
        lon, lat = utm.to_lonlat(east, north)
        e2, n2 = to_utm.transform(lon, lat)  # ours -> lon/lat -> PROJ's metres
        assert float(np.hypot(e2 - east, n2 - north).max()) < 1e-3
        e3, n3 = utm.from_lonlat(*to_lonlat.transform(east, north))  # PROJ's lon/lat -> ours
        assert float(np.hypot(e3 - east, n3 - north).max()) < 1e-3


def test_a_local_tangent_plane_across_180_deg_converts_both_ways() -> None:
    plane = Projection("local_tangent_plane", ref_lat=-17.0, ref_lon=179.99, ref_en=(0.0, 0.0))
    east = np.linspace(-3_000.0, 3_000.0, 13)
    lon, lat = plane.to_lonlat(east, np.zeros_like(east))
    assert (np.abs(lon) <= 180).all() and lon[0] > 179 and lon[-1] < -179
    e, n = plane.from_lonlat(lon, lat)
    assert np.allclose(e, east, atol=1e-6) and np.allclose(n, 0.0, atol=1e-6)


@pytest.mark.parametrize(
    ("transform", "said"),
    [
        (Affine(5.0, 0.5, 487_000.0, 0.5, -5.0, 5_208_000.0), "not a north-up grid"),
        (Affine(5.0, 0.0, 487_000.0, 0.0, 5.0, 5_208_000.0), "not a north-up grid"),
    ],
    ids=["rotated", "south_up"],
)
def test_a_rotated_or_south_up_geotiff_is_called_not_north_up_by_both_readers(
    tmp_path: Path, transform: Affine, said: str
) -> None:
    tif = naip_as(tmp_path, "turned", "EPSG:26914", transform)
    with tifffile.TiffFile(tif) as t:
        assert MODEL_TRANSFORMATION in t.pages.first.tags  # how GDAL wrote it
    for use_rasterio in (True, False):
        with pytest.raises(InvalidInputError, match=said) as got:
            build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
        assert "no georeference" not in str(got.value)


def test_a_north_up_grid_given_by_a_model_transformation_is_read_by_both_readers(
    tmp_path: Path,
) -> None:
    with rasterio.open(NAIP_2020) as ds:
        rgb = np.ascontiguousarray(ds.read([1, 2, 3]).transpose(1, 2, 0))
        t = ds.transform
    matrix = (t.a, 0.0, 0.0, t.c, 0.0, t.e, 0.0, t.f, 0, 0, 0, 0, 0, 0, 0, 1)
    keys = projected_keys(26914)
    tif = tmp_path / "matrix.tif"
    tifffile.imwrite(
        tif,
        rgb,
        photometric="rgb",
        extratags=[
            (MODEL_TRANSFORMATION, "d", 16, matrix, True),
            (GEO_KEY_DIRECTORY, "H", len(keys), keys, True),
        ],
    )
    plain = build_mbtiles(NAIP_2020, tmp_path / "plain.mbtiles", use_rasterio=False)
    ours = build_mbtiles(tif, tmp_path / "t.mbtiles", use_rasterio=False)
    gdal = build_mbtiles(tif, tmp_path / "r.mbtiles", use_rasterio=True)
    assert stored(ours.path).keys() == stored(plain.path).keys() == stored(gdal.path).keys()
    for key, tile in stored(ours.path).items():
        assert np.array_equal(tile, stored(plain.path)[key])
