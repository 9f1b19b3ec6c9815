"""``tiles build`` refuses nonsense before writing anything, says how it maps non-8-bit data,
and writes atomically; on GeoTIFFs derived from the shipped NAIP sheet (real imagery, rewritten
with a wrong CRS, other bit depths or no data)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.geotiff import write_geotiff
from c3_matcher_tools.tilestore.build import build_mbtiles

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
READERS = pytest.mark.parametrize("use_rasterio", [True, False], ids=["rasterio", "tifffile"])


def derived(
    tmp_path: Path, name: str, scale: Any = None, dtype: str = "uint8", **profile: Any
) -> Path:
    """The NAIP sheet's RGB bands times ``scale`` as ``dtype``, with ``profile`` overrides."""
    with rasterio.open(NAIP_2020) as ds:
        data = ds.read([1, 2, 3]).astype(np.float64)
        base = dict(ds.profile, count=3, dtype=dtype)
    base.pop("photometric", None)
    if scale is not None:
        data = data * scale
    path = tmp_path / name
    with rasterio.open(path, "w", **{**base, **profile}) as out:
        out.write(data.astype(dtype))
    return path


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@READERS
def test_utm_metres_labelled_degrees_are_refused(tmp_path: Path, use_rasterio: bool) -> None:
    tif = derived(tmp_path, "wrong.tif", crs="EPSG:4326")
    with pytest.raises(InvalidInputError, match=r"do not fit EPSG:4326.*degrees"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    assert not (tmp_path / "o.mbtiles").exists()


def test_degrees_labelled_utm_metres_are_refused(tmp_path: Path) -> None:
    tif = derived(
        tmp_path, "deg.tif", crs="EPSG:32614", transform=from_origin(-99.16, 47.03, 6e-5, 4e-5)
    )
    with pytest.raises(InvalidInputError, match="do not fit EPSG:32614"):
        build_mbtiles(tif, tmp_path / "o.mbtiles")


def test_coordinates_outside_the_crs_area_of_use_are_refused(tmp_path: Path) -> None:
    tif = derived(tmp_path, "swiss.tif", crs="EPSG:2056")  # UTM 14N numbers as Swiss LV95
    with pytest.raises(InvalidInputError, match="EPSG:2056.*is the CRS right"):
        build_mbtiles(tif, tmp_path / "o.mbtiles")


def test_implausible_pixel_size_is_refused(tmp_path: Path) -> None:
    tif = derived(tmp_path, "tiny.tif", transform=from_origin(487_000.0, 5_208_000.0, 1e-5, 1e-5))
    with pytest.raises(InvalidInputError, match="not plausible"):
        build_mbtiles(tif, tmp_path / "o.mbtiles")


@READERS
def test_plain_png_says_no_georeference(tmp_path: Path, use_rasterio: bool) -> None:
    png = tmp_path / "plain.png"
    cv2.imwrite(str(png), cv2.imread(str(REPO / "data" / "demo" / "tile_a.png")))
    with pytest.raises(InvalidInputError, match="no georeference"):
        build_mbtiles(png, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)


def test_zoom_far_finer_than_the_source_needs_force(tmp_path: Path) -> None:
    out = tmp_path / "z.mbtiles"
    with pytest.raises(InvalidInputError, match=r"zoom 22 .*400,644 tiles planned.*--force"):
        build_mbtiles(NAIP_2020, out, zoom=22)
    with pytest.raises(InvalidInputError, match=r"zoom 17 .*--force"):
        build_mbtiles(NAIP_2020, out, zoom=17)
    assert not out.exists() and not leftovers(tmp_path)
    report = build_mbtiles(NAIP_2020, out, zoom=16)  # 3x finer than the 5 m source: allowed
    assert report.tiles > 0


def test_forced_fine_zoom_builds(tmp_path: Path) -> None:
    with rasterio.open(NAIP_2020) as ds:  # a 40 x 40 px corner keeps the forced build small
        window = rasterio.windows.Window(400, 300, 40, 40)
        data = ds.read([1, 2, 3], window=window)
        profile = dict(ds.profile, count=3, width=40, height=40)
        profile.update(transform=ds.window_transform(window))
    profile.pop("photometric", None)
    small = tmp_path / "small.tif"
    with rasterio.open(small, "w", **profile) as out:
        out.write(data)
    report = build_mbtiles(small, tmp_path / "f.mbtiles", zoom=17, force=True)
    assert report.tiles > 0 and report.zoom == 17


def test_all_nodata_raster_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    tif = derived(tmp_path, "zeros.tif", scale=0)
    with pytest.raises(InvalidInputError, match="no tile holds data"):
        build_mbtiles(tif, tmp_path / "o.mbtiles")
    assert not (tmp_path / "o.mbtiles").exists() and not leftovers(tmp_path)


def _tiles(path: Path) -> dict[tuple[int, int, int], bytes]:
    with MBTilesStore(path) as store:
        return {
            (z, x, y): bytes(store.tile_bytes(z, x, y) or b"")
            for z in store.zooms()
            for x, y in store.tiles(z)
        }


def test_non_8_bit_mapping_is_stated_and_selectable(tmp_path: Path) -> None:
    u8 = build_mbtiles(NAIP_2020, tmp_path / "u8.mbtiles")
    assert u8.value_mapping == "uint8 as is"
    u16 = derived(tmp_path, "u16.tif", scale=257, dtype="uint16")
    u12 = derived(tmp_path, "u12.tif", scale=16, dtype="uint16", NBITS=12)
    f32 = derived(tmp_path, "f32.tif", scale=1 / 255, dtype="float32")
    auto = {
        name: build_mbtiles(tif, tmp_path / f"{name}.mbtiles")
        for name, tif in (("u16", u16), ("u12", u12), ("f32", f32))
    }
    for name, report in auto.items():
        assert "99.9th percentile" in report.value_mapping, name
    assert auto["u12"].value_mapping.startswith("uint16 0..")
    assert auto["f32"].value_mapping.startswith("float32 0..")
    bits = build_mbtiles(u12, tmp_path / "bits.mbtiles", value_range="bits")
    assert bits.value_mapping == "uint16 0..4095 -> 0..255 linear (declared bit depth NBITS=12)"
    given = build_mbtiles(u16, tmp_path / "given.mbtiles", value_range=(0.0, 65535.0))
    assert given.value_mapping.endswith("(given)")
    # the declared 12-bit range keeps the source's brightness: 16 v / 4095 * 255 ~ v
    a, b = _tiles(u8.path), _tiles(bits.path)
    assert a.keys() == b.keys()
    key = sorted(a)[len(a) // 2]
    ia = cv2.imdecode(np.frombuffer(a[key], np.uint8), cv2.IMREAD_COLOR).astype(int)
    ib = cv2.imdecode(np.frombuffer(b[key], np.uint8), cv2.IMREAD_COLOR).astype(int)
    assert float(np.abs(ia - ib).mean()) < 1.5
    with MBTilesStore(bits.path) as store:
        assert store.metadata["c3_source_value_mapping"] == bits.value_mapping
    with pytest.raises(InvalidInputError, match="no bit depth"):
        build_mbtiles(f32, tmp_path / "x.mbtiles", value_range="bits")


class Interrupt(KeyboardInterrupt):
    pass


def test_interrupted_build_leaves_nothing_and_keeps_the_old_store(tmp_path: Path) -> None:
    out = tmp_path / "o.mbtiles"

    def stop(done: int, total: int) -> None:
        if done == 5:
            raise Interrupt

    with pytest.raises(Interrupt):
        build_mbtiles(NAIP_2020, out, progress=stop)
    assert not out.exists() and not leftovers(tmp_path)
    first = build_mbtiles(NAIP_2020, out, zoom=14)
    before = out.read_bytes()
    with pytest.raises(Interrupt):
        build_mbtiles(NAIP_2020, out, overwrite=True, progress=stop)
    assert out.read_bytes() == before and not leftovers(tmp_path)
    assert first.tiles == len(_tiles(out))


GEOGRAPHIC_KEYS = (1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326)
"""GeoKeys of a WGS84 lon/lat grid (PixelIsArea)."""


def tiny_geotiff(
    path: Path,
    *,
    scale: tuple[float, float] = (1e-5, 1e-5),
    tie: tuple[float, float] = (10.0, 50.0),
    keys: tuple[int, ...] = GEOGRAPHIC_KEYS,
    compression: str | None = None,
) -> Path:
    """A 64 x 64 px RGB GeoTIFF of noise written tag by tag with tifffile (any pixel scale or
    EPSG code, which GDAL would not write): its top-left corner at ``tie`` in the CRS of
    ``keys``, ``scale`` CRS units per pixel."""
    image = np.random.default_rng(0).integers(1, 255, (64, 64, 3), dtype=np.uint8)
    return write_geotiff(path, image, scale=scale, top_left=tie, keys=keys, compression=compression)


def truncated(path: Path) -> Path:
    """``path`` cut to half its length: its header and tags whole, its pixel data not."""
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    return path


@READERS
def test_truncated_geotiff_is_refused_naming_the_file(tmp_path: Path, use_rasterio: bool) -> None:
    tif = truncated(tiny_geotiff(tmp_path / "cut.tif", compression="zlib"))
    with pytest.raises(InvalidInputError, match=r"cut\.tif: damaged .*(decompress|Read error)"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    assert not (tmp_path / "o.mbtiles").exists() and not leftovers(tmp_path)


@READERS
def test_epsg_code_proj_does_not_know_needs_a_reference(tmp_path: Path, use_rasterio: bool) -> None:
    keys = (1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 9999)
    tif = tiny_geotiff(tmp_path / "local.tif", scale=(0.5, 0.5), tie=(5e5, 5.2e6), keys=keys)
    with pytest.raises(InvalidInputError, match=r"local\.tif: .*PROJ.*--ref-latlon"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)
    report = build_mbtiles(
        tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio, reference=(47.0, -99.0)
    )
    assert report.tiles > 0 and report.georeference.startswith("local tangent plane")


@READERS
def test_negative_pixel_scale_is_not_a_north_up_grid(tmp_path: Path, use_rasterio: bool) -> None:
    tif = tiny_geotiff(tmp_path / "flipped.tif", scale=(-1e-5, 1e-5))
    with pytest.raises(InvalidInputError, match=r"flipped\.tif: not a north-up grid"):
        build_mbtiles(tif, tmp_path / "o.mbtiles", use_rasterio=use_rasterio)


@READERS
def test_complex_pixels_are_refused_naming_their_type(tmp_path: Path, use_rasterio: bool) -> None:
    """A complex-valued raster (a radar product's) has no brightness to map: refused by its
    type, once an internal error (rasterio) or silently cast to its real part (tifffile)."""
    source = derived(tmp_path, "c64.tif", dtype="complex64")
    with pytest.raises(InvalidInputError, match=r"c64.tif: its pixels are complex64"):
        build_mbtiles(source, tmp_path / "out.mbtiles", zoom=16, use_rasterio=use_rasterio)
    assert not (tmp_path / "out.mbtiles").exists()


def test_a_fifo_as_the_geotiff_is_named_so(tmp_path: Path) -> None:
    fifo = tmp_path / "ortho.tif"
    os.mkfifo(fifo)
    proc = run_cli("tiles", "build", fifo, tmp_path / "out.mbtiles", cwd=tmp_path, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert f"geotiff: {fifo}: is a FIFO, not a GeoTIFF" in proc.stderr
    with pytest.raises(InvalidInputError, match=r"is a FIFO, not a GeoTIFF"):
        build_mbtiles(fifo, tmp_path / "out.mbtiles", use_rasterio=True)
