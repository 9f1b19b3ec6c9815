"""A palette (colour-mapped) GeoTIFF given to ``tiles build``: both readers expand its colour
map to RGB, so its tiles are the tiles of the same picture written as RGB (its indices read as
grey were noise)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from PIL import Image
from rasterio.windows import Window

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.tilestore.build import build_mbtiles
from c3_matcher_tools.tilestore.raster import RasterioSource

from .conftest import stored_tiles

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"


def _sheets(tmp_path: Path) -> tuple[Path, Path]:
    """(palette GeoTIFF, RGB GeoTIFF of the same colours) of a 384 px crop of a NAIP sheet,
    reduced to 200 colours; palette index 0 (black) stays nodata-black in both."""
    with rasterio.open(NAIP_2020) as ds:
        window = Window(200, 200, 384, 384)
        rgb = np.moveaxis(ds.read([1, 2, 3], window=window), 0, -1)
        profile = {
            "driver": "GTiff",
            "width": 384,
            "height": 384,
            "crs": ds.crs,
            "transform": ds.window_transform(window),
        }
    quantised = Image.fromarray(np.ascontiguousarray(rgb)).quantize(200, dither=Image.Dither.NONE)
    indices = np.asarray(quantised, dtype=np.uint8) + 1  # 1..200: no index is nodata black
    colours = np.asarray(quantised.getpalette()[: 3 * 200], dtype=np.uint8).reshape(200, 3)
    colours = np.maximum(colours, 1)  # no colour is all zero (nodata)
    table = {0: (0, 0, 0, 255)} | {i + 1: (*map(int, c), 255) for i, c in enumerate(colours)}
    palette, plain = tmp_path / "palette.tif", tmp_path / "rgb.tif"
    with rasterio.open(palette, "w", count=1, dtype="uint8", photometric="palette", **profile) as o:
        o.write(indices, 1)
        o.write_colormap(1, table)
    expanded = np.zeros((201, 3), np.uint8)
    expanded[1:] = colours
    with rasterio.open(plain, "w", count=3, dtype="uint8", **profile) as o:
        o.write(np.moveaxis(expanded[indices], -1, 0))
    return palette, plain


@pytest.mark.parametrize("use_rasterio", [True, False], ids=["rasterio", "tifffile"])
def test_a_palette_geotiff_gives_the_tiles_of_its_colours(
    tmp_path: Path, use_rasterio: bool
) -> None:
    palette, plain = _sheets(tmp_path)
    got = build_mbtiles(palette, tmp_path / "p.mbtiles", use_rasterio=use_rasterio)
    want = build_mbtiles(plain, tmp_path / "r.mbtiles", use_rasterio=use_rasterio)
    assert got.reader == ("rasterio" if use_rasterio else "tifffile")
    tp, tr = stored_tiles(got.path), stored_tiles(want.path)
    assert tp.keys() == tr.keys() and tp
    diff = np.concatenate([np.abs(tp[k].astype(int) - tr[k].astype(int)).ravel() for k in tp])
    assert float(diff.mean()) < 0.05 and int(diff.max()) <= 2, (diff.mean(), diff.max())


def test_both_readers_expand_the_colour_map_alike(tmp_path: Path) -> None:
    palette, plain = _sheets(tmp_path)
    with rasterio.open(plain) as ds:
        want = np.moveaxis(ds.read(), 0, -1)
    assert np.array_equal(load_orthophoto(palette).rgb, want)
    with RasterioSource(palette) as src:
        uv = np.array([[0.0, 0.0], [383.0, 383.0]])
        sampled = src.sample(uv, 1.0)
        assert sampled is not None
        assert np.array_equal(sampled[0], want)
        assert "colour map" in src.mapping.describe()


def test_a_value_range_for_a_palette_is_refused_naming_it(tmp_path: Path) -> None:
    palette, _ = _sheets(tmp_path)
    with pytest.raises(InvalidInputError, match="palette image"):
        RasterioSource(palette, value_range="bits")
