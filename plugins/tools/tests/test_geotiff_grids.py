"""GeoTIFF grids the readers once got wrong, each written tag by tag here: a state-plane grid in
feet (its GSD was read as metres, 3.28x off), a NAD83 geographic grid (EPSG:4269, whose area of
use crosses the antimeridian, was refused), malformed geo tags (an internal error, never a
refusal naming the file) and the tifffile fallback's downscale, whose height was scaled by the
width's factor (tiles misplaced vertically by up to half a tile pixel)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
from numpy.typing import NDArray

from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.tilestore.build import build_mbtiles, render_tile
from c3_matcher_tools.tilestore.geo import read_geotiff_grid

READERS = pytest.mark.parametrize("use_rasterio", [True, False], ids=["rasterio", "tifffile"])
#: NAD83 / North Dakota South (ft), EPSG:2266: (E, N) international feet of lon -99.15, lat 47.02
ND_SOUTH_FT = (2_305_203.99, 496_440.39)
FT = 0.3048


def _keys(*pairs: tuple[int, int]) -> list[int]:
    """A GeoKeyDirectory of inline keys."""
    out = [1, 1, 0, len(pairs)]
    for key, value in pairs:
        out += [key, 0, 1, value]
    return out


def _write(
    path: Path,
    image: NDArray[np.uint8],
    *,
    scale: Any = (0.5, 0.5, 0.0),
    tie: Any = (0.0, 0.0, 0.0, 500_000.0, 5_208_000.0, 0.0),
    keys: Any = None,
) -> Path:
    """``image`` (RGB) with the raw tags given (the count of each tag is its length: a
    malformed tag is written as it is); keys default to WGS84 UTM 14N."""
    keys = _keys((1024, 1), (1025, 1), (3072, 32614)) if keys is None else keys
    extra = [
        (33550, "d", len(scale), tuple(scale), True),
        (33922, "d", len(tie), tuple(tie), True),
        (34735, "H", len(keys), tuple(keys), True),
    ]
    tifffile.imwrite(path, image, photometric="rgb", extratags=extra)
    return path


def _texture(h: int, w: int, seed: int = 0) -> NDArray[np.uint8]:
    rng = np.random.default_rng(seed)
    grey = cv2.GaussianBlur(rng.integers(1, 255, (h, w), dtype=np.uint8), (0, 0), 2)
    return np.repeat(np.clip(grey, 1, 255)[:, :, None], 3, axis=2)


def _feet_grid(tmp_path: Path, *, declared: bool) -> Path:
    """A 120 x 100 px grid of 16.4 ft (5 m) pixels in EPSG:2266 at lon -99.15, lat 47.02; its
    ProjLinearUnitsGeoKey (9002, foot) written as GDAL writes it, or left to the EPSG code."""
    keys = [(1024, 1), (1025, 1), (3072, 2266)] + ([(3076, 9002)] if declared else [])
    e, n = ND_SOUTH_FT
    top_left = (e - 60 * 16.4, n + 50 * 16.4)
    return _write(
        tmp_path / f"feet_{declared}.tif",
        _texture(100, 120),
        scale=(16.4, 16.4, 0.0),
        tie=(0.0, 0.0, 0.0, *top_left, 0.0),
        keys=_keys(*keys),
    )


# --- (A) a projected CRS in feet ------------------------------------------------------------


@pytest.mark.parametrize("declared", [True, False], ids=["unit-key", "epsg-unit"])
def test_feet_grid_gsd_is_in_metres(tmp_path: Path, declared: bool) -> None:
    tif = _feet_grid(tmp_path, declared=declared)
    assert load_orthophoto(tif).gsd_m == pytest.approx(16.4 * FT, rel=1e-9)  # not 16.4
    grid = read_geotiff_grid(tif)
    assert grid.projection.kind == "pyproj" and grid.unit_m == pytest.approx(FT)
    lon, lat = grid.centre_lonlat()
    assert lon == pytest.approx(-99.15, abs=1e-3) and lat == pytest.approx(47.02, abs=1e-3)


@READERS
def test_feet_grid_builds_at_the_zoom_of_its_metres(tmp_path: Path, use_rasterio: bool) -> None:
    tif = _feet_grid(tmp_path, declared=True)
    report = build_mbtiles(tif, tmp_path / "ft.mbtiles", use_rasterio=use_rasterio)
    assert report.source_gsd_m == pytest.approx(16.4 * FT, rel=1e-3)
    assert report.zoom == 15  # 3.26 m/px tiles for a 5 m source; read as metres: zoom 13


def test_units_of_projected_crss() -> None:
    from c3_matcher_tools.geodesy import ground_gsd_m, projected_unit

    assert projected_unit(2266) == ("foot", FT)
    assert projected_unit(32614)[1] == 1.0 and projected_unit(None)[1] == 1.0
    assert projected_unit(32614, unit_code=9003)[1] == pytest.approx(1200 / 3937)
    assert ground_gsd_m(10.0, 10.0, 47.0, geographic=False, epsg=2266, unit_m=FT) == 3.048
    with pytest.raises(InvalidInputError, match="linear unit 32767"):
        projected_unit(2266, unit_code=32767)  # user-defined: its size is not known


def test_feet_grid_without_pyproj_is_refused_not_read_as_metres(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_PYPROJ", "1")  # the local tangent plane takes metres
    tif = _feet_grid(tmp_path, declared=True)
    with pytest.raises(InvalidInputError, match=r"units of 0.3048 m \(EPSG:2266\).*pyproj") as e:
        read_geotiff_grid(tif, reference=(47.02, -99.15))
    assert e.value.field == "geotiff"


# --- (B) an area of use across the antimeridian ----------------------------------------------


def _nad83_degrees(tmp_path: Path, lon: float, lat: float) -> Path:
    """A 100 x 100 px NAD83 (EPSG:4269) geographic grid of about 4.5 m pixels at (lon, lat)."""
    return _write(
        tmp_path / f"nad83_{lon}.tif",
        _texture(100, 100, seed=1),
        scale=(6e-5, 4e-5, 0.0),
        tie=(0.0, 0.0, 0.0, lon, lat, 0.0),
        keys=_keys((1024, 2), (1025, 1), (2048, 4269)),
    )


@READERS
def test_nad83_degrees_in_north_dakota_are_in_its_area_of_use(
    tmp_path: Path, use_rasterio: bool
) -> None:
    tif = _nad83_degrees(tmp_path, -99.15, 47.02)  # pyproj: lon 167.65 .. -40.73 (across 180)
    grid = read_geotiff_grid(tif)
    assert grid.epsg == 4269 and grid.projection.kind == "pyproj"
    report = build_mbtiles(tif, tmp_path / "nad83.mbtiles", zoom=15, use_rasterio=use_rasterio)
    assert report.tiles > 0


def test_nad83_degrees_in_europe_are_still_outside_its_area_of_use(tmp_path: Path) -> None:
    tif = _nad83_degrees(tmp_path, 10.0, 50.0)
    with pytest.raises(InvalidInputError, match="outside EPSG:4269's area of use"):
        read_geotiff_grid(tif)


# --- (C) malformed geo tags ---------------------------------------------------------------

MERCATOR_KEYS = _keys((1024, 1), (1025, 1), (3072, 3395))  # its GSD needs the tie point
MALFORMED = {
    "truncated-key-directory": {"keys": [1, 1, 0, 5, 1024, 0, 1, 1]},
    "key-count-past-the-end": {"keys": [1, 1, 0, 3, 1024, 0, 1, 1, 3072, 0, 1, 32614]},
    "key-directory-without-header": {"keys": [1, 1]},
    "one-number-pixel-scale": {"scale": (0.5,)},
    "short-tie-point": {"tie": (0.0, 0.0, 0.0, 500_000.0), "keys": MERCATOR_KEYS},
}


@pytest.mark.parametrize("tags", list(MALFORMED.values()), ids=list(MALFORMED))
def test_malformed_geo_tags_are_refused_naming_the_file(
    tmp_path: Path, tags: dict[str, Any]
) -> None:
    tif = _write(tmp_path / "bad.tif", _texture(30, 40), **tags)
    for read in (read_geotiff_grid, load_orthophoto):
        with pytest.raises(InvalidInputError, match=r"bad\.tif: malformed GeoTIFF") as e:
            read(tif)
        assert e.value.field == "geotiff"
    with pytest.raises(InvalidInputError, match="malformed GeoTIFF"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=False)
    assert not (tmp_path / "o.mbtiles").exists()


def test_malformed_key_directory_is_a_refusal_on_the_command_line(tmp_path: Path, c3: Any) -> None:
    _write(tmp_path / "bad.tif", _texture(30, 40), **MALFORMED["truncated-key-directory"])
    done = c3("tiles", "build", "bad.tif", "o.mbtiles", "--reader", "tifffile")
    assert done.returncode != 0
    assert "malformed GeoTIFF" in done.stderr and "internal error" not in done.stderr


# --- (D) the tifffile fallback's downscale, each axis its own --------------------------------


def _ramp_grid(tmp_path: Path) -> Path:
    """A 0.5 m UTM grid whose height is half a pixel off a whole number of zoom-16 tile pixels
    and whose width is a whole number (the width's scale is the wrong one for the height);
    green ramps down the rows, red along the columns (linear: resampling keeps it exact)."""
    lat = read_geotiff_grid(_write(tmp_path / "probe.tif", _texture(8, 8))).centre_lonlat()[1]
    ratio = TileId(16, lat, -99.0).web_mercator_gsd_m() / 0.5
    h = next(h for h in range(80, 200) if abs((h / ratio) % 1 - 0.5) < 0.05)
    w = next(w for w in range(80, 200) if min((w / ratio) % 1, 1 - (w / ratio) % 1) < 0.05)
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    image = np.zeros((h, w, 3), np.uint8)
    image[:, :, 0] = np.rint(10 + 240 * cols / w)
    image[:, :, 1] = np.rint(10 + 240 * rows / h)
    image[:, :, 2] = 100
    return _write(tmp_path / "ramp.tif", image)


def test_tifffile_downscale_keeps_rows_in_place(tmp_path: Path) -> None:
    tif = _ramp_grid(tmp_path)
    out = build_mbtiles(tif, tmp_path / "ramp.mbtiles", zoom=16, use_rasterio=False).path
    grid = read_geotiff_grid(tif)
    full = np.asarray(tifffile.imread(tif))
    valid = np.ones(full.shape[:2], np.uint8)
    worst = 0.0
    with MBTilesStore(out) as store:
        for x, y in store.tiles(16):
            tile = cv2.imdecode(np.frombuffer(store.tile_bytes(16, x, y) or b"", np.uint8), 1)
            got = tile[:, :, ::-1].astype(np.float64)  # BGR -> RGB
            want = render_tile(full, valid, grid, 16, x, y)  # full resolution: no downscale
            assert want is not None
            both = ((got[:, :, 2] > 0) & (want[:, :, 2] > 0)).astype(np.uint8)
            inside = cv2.erode(both, np.ones((7, 7), np.uint8)) > 0  # away from the edges
            if inside.any():
                worst = max(worst, float(np.abs(got - want)[inside].max()))
    print(f"worst ramp difference, tifffile downscale vs full resolution: {worst:.2f}")
    assert worst <= 2.0  # with the width's scale for both: about 5 at the bottom
