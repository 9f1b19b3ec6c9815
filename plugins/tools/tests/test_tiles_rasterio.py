"""``tiles build`` through rasterio (windowed reads, nodata tag, overviews, multi-zoom) against
the tifffile fallback and pyproj/GDAL transforms, on the shipped orthophotos."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pyproj  # the tools' geo extra (scripts/setup installs it): never skipped
import pytest
import rasterio

from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.geo import read_geotiff_grid, world_px_to_lonlat
from c3_matcher_tools.tilestore.raster import RasterioSource

from .conftest import stored_tiles

REPO = Path(__file__).resolve().parents[3]
IMAGERY = REPO / "data" / "imagery"
NAIP_2020 = IMAGERY / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
# deflate (lossless) sheets decode identically in both readers; JPEG-in-TIFF sheets are decoded
# by GDAL's libjpeg vs OpenCV's (tifffile lacks imagecodecs here), hence a tolerance
SHEETS = {
    NAIP_2020: (0.001, 0),
    IMAGERY / "open_orthophotos" / "swissimage_ref-img_0p5m.tif": (0.001, 0),
    IMAGERY / "open_orthophotos" / "swissimage_zurich_1091-322_00_0p5m.tif": (1.0, 12),
    IMAGERY / "open_orthophotos" / "test_tiled.tif": (1.0, 12),
}


@pytest.mark.parametrize("sheet", list(SHEETS), ids=lambda p: p.name)
def test_rasterio_tiles_match_the_tifffile_fallback(sheet: Path, tmp_path: Path) -> None:
    mean_tol, p99_tol = SHEETS[sheet]
    a = build_mbtiles(sheet, tmp_path / "r.mbtiles", use_rasterio=True)
    b = build_mbtiles(sheet, tmp_path / "t.mbtiles", use_rasterio=False)
    assert a.reader == "rasterio" and b.reader == "tifffile"
    assert a.zooms == b.zooms and abs(a.source_gsd_m - b.source_gsd_m) < 1e-9
    ta, tb = stored_tiles(a.path), stored_tiles(b.path)
    assert ta.keys() == tb.keys() and ta
    diff = np.concatenate(
        [np.abs(ta[k].astype(np.int16) - tb[k].astype(np.int16)).ravel() for k in ta]
    )
    mean, p99, top = float(diff.mean()), float(np.percentile(diff, 99)), int(diff.max())
    print(
        f"{sheet.name}: z{a.zoom} {len(ta)} tiles, |rasterio - tifffile| mean {mean:.4f} "
        f"p99 {p99:.0f} max {top}"
    )
    assert mean <= mean_tol and p99 <= p99_tol


@pytest.mark.parametrize("sheet", list(SHEETS), ids=lambda p: p.name)
def test_rasterio_grid_matches_tags_and_gdal_transform(sheet: Path) -> None:

    tags = read_geotiff_grid(sheet)
    with RasterioSource(sheet) as src, rasterio.open(sheet) as ds:
        grid = src.grid
        assert grid.size == tags.size and grid.epsg == tags.epsg
        assert abs(grid.origin_e - tags.origin_e) < 1e-6
        assert abs(grid.origin_n - tags.origin_n) < 1e-6
        assert abs(grid.scale_x - tags.scale_x) < 1e-9 and abs(grid.scale_y - tags.scale_y) < 1e-9
        w, h = grid.size
        pts = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, h / 3]], float)
        xs, ys = rasterio.transform.xy(ds.transform, pts[:, 1], pts[:, 0], offset="center")
        to_wgs = pyproj.Transformer.from_crs(ds.crs, "EPSG:4326", always_xy=True)
        lon, lat = to_wgs.transform(np.asarray(xs), np.asarray(ys))
        ours = grid.px_to_lonlat(pts)
        geod = pyproj.Geod(ellps="WGS84")
        _, _, dist = geod.inv(ours[:, 0], ours[:, 1], lon, lat)
        print(f"{sheet.name}: rasterio grid vs GDAL+pyproj, max {float(np.max(dist)):.2e} m")
        assert float(np.max(dist)) < 1e-3


def _nodata_tif(path: Path) -> np.ndarray:
    from rasterio.transform import from_origin

    rng = np.random.default_rng(0)
    img = rng.integers(20, 235, size=(3, 400, 400), dtype=np.uint8)
    img[:, :, :150] = 255  # the nodata tag's value: must become transparent, not white
    profile = {
        "driver": "GTiff", "width": 400, "height": 400, "count": 3, "dtype": "uint8",
        "crs": "EPSG:32633", "transform": from_origin(500000.0, 5300000.0, 1.0, 1.0),
        "nodata": 255, "tiled": True, "blockxsize": 128, "blockysize": 128,
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(img)
    return img


def test_nodata_tag_becomes_zero_and_masked(tmp_path: Path) -> None:
    tif = tmp_path / "nodata.tif"
    _nodata_tif(tif)
    with RasterioSource(tif) as src:
        assert src.nodata == 255
        grid = src.grid
    report = build_mbtiles(tif, tmp_path / "n.mbtiles", use_rasterio=True)
    assert report.nodata == 255
    with MBTilesStore(report.path) as st:
        assert st.metadata["c3_source_nodata"] == "255.0"
    tiles = stored_tiles(report.path)
    white = inside = 0
    for (z, x, y), img in tiles.items():
        i = np.arange(256) + 0.5
        wx, wy = np.meshgrid(x * 256 + i, y * 256 + i)
        uv = grid.lonlat_to_px(world_px_to_lonlat(np.stack([wx.ravel(), wy.ravel()], 1), z))
        u, v = uv[:, 0].reshape(256, 256), uv[:, 1].reshape(256, 256)
        nod = (u > 2) & (u < 147) & (v > 2) & (v < 397)
        data = (u > 152) & (u < 397) & (v > 2) & (v < 397)
        assert (img[nod] == 0).all()  # nodata -> 0 (the matcher's tile nodata)
        white += int((img[nod] == 255).all(axis=1).sum())
        inside += int((img[data] > 0).any(axis=1).sum())
        assert (img[data] > 0).any(axis=1).mean() > 0.99
    assert white == 0 and inside > 1000
    # the fallback ignores the tag: the same area is white there
    fb = stored_tiles(build_mbtiles(tif, tmp_path / "f.mbtiles", use_rasterio=False).path)
    assert any((img == 255).all(axis=2).sum() > 1000 for img in fb.values())


@pytest.mark.parametrize("kind", ["float_nan_nodata", "rgba_with_nodata"])
def test_nodata_a_library_would_warn_about_builds_quietly(tmp_path: Path, kind: str) -> None:
    """A float raster whose nodata is NaN and an RGBA raster with a nodata tag too build their
    tiles without a library warning on stderr: NaN pixels are 0 like every invalid one, and the
    mask follows the tag (GDAL's rule) as the module says."""
    from rasterio.transform import from_origin

    rng = np.random.default_rng(0)
    count, dtype, nodata = (3, "float32", float("nan")) if kind == "float_nan_nodata" else (
        4, "uint8", 255)  # fmt: skip
    img = rng.uniform(20, 235, size=(count, 300, 300)).astype(dtype)
    img[:, :, :100] = nodata
    tif = tmp_path / f"{kind}.tif"
    profile = {
        "driver": "GTiff", "width": 300, "height": 300, "count": count, "dtype": dtype,
        "crs": "EPSG:32633", "transform": from_origin(500000.0, 5300000.0, 1.0, 1.0),
        "nodata": nodata, **({"photometric": "RGB", "alpha": "YES"} if count == 4 else {}),
    }  # fmt: skip
    with rasterio.open(tif, "w", **profile) as ds:
        ds.write(img)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails the build
        report = build_mbtiles(tif, tmp_path / "t.mbtiles", use_rasterio=True)
    tiles = stored_tiles(report.path)
    assert tiles and any((img > 0).any() for img in tiles.values())


def test_multi_zoom_store_with_overviews_reads_back(tmp_path: Path) -> None:
    report = build_mbtiles(NAIP_2020, tmp_path / "m.mbtiles", zoom=[13, 14, 15, 16])
    assert report.reader == "rasterio" and report.zooms == (13, 14, 15, 16)
    assert 0 in report.overview_levels  # z13 (13 m/px) reads NAIP's 2x overview
    with MBTilesStore(report.path) as st:
        assert st.zooms() == [13, 14, 15, 16]
        assert st.metadata["minzoom"] == "13" and st.metadata["maxzoom"] == "16"
        counts = {z: len(list(st.tiles(z))) for z in st.zooms()}
        assert counts == {int(z): n for z, n in (report.tiles_per_zoom or {}).items()}
        assert counts[16] > counts[15] > counts[14] >= counts[13] >= 1
    fallback = stored_tiles(build_mbtiles(NAIP_2020, tmp_path / "f.mbtiles", zoom=[13, 14, 15, 16],
                                    use_rasterio=False).path)  # fmt: skip
    ours = stored_tiles(report.path)
    assert ours.keys() == fallback.keys()
    for z in (13, 14, 15, 16):
        d = np.concatenate([np.abs(ours[k].astype(np.int16) - fallback[k]).ravel()
                            for k in ours if k[0] == z])  # fmt: skip
        print(
            f"NAIP z{z}: |rasterio - tifffile| mean {d.mean():.3f} p99 "
            f"{np.percentile(d, 99):.0f} max {d.max()}"
        )
        assert d.mean() < (0.01 if z >= 15 else 3.0)
