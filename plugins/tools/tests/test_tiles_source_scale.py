"""``tiles build`` reports the source's ground GSD, not its grid's: on a projected CRS whose
scale factor at the orthophoto is not 1 (PDC Mercator at 17 S: 1.045; Antarctic polar
stereographic at 77.7 S: 0.984) a 5-unit pixel is 4.78 m (5.08 m) on the ground, and both
readers (rasterio and the tifffile fallback) say so alike; that figure also picks the default
zoom and is written to the store's metadata."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.testing.geotiff import projected_keys, write_geotiff
from c3_matcher_tools.tilestore.build import build_mbtiles

SCALE = 5.0
SIZE = (160, 120)  # w, h px

#: (EPSG code, top-left corner E, N): PDC Mercator at 17 S 170 E, polar stereographic 77.7 S
GRIDS = {
    "pdc_mercator": (3832, 2223900.0, -1908339.0),
    "polar_stereographic": (3031, 300000.0, -1300000.0),
}


def _ground_px_m(epsg: int, centre_en: tuple[float, float]) -> float:
    """One pixel's ground size (m, geometric mean of E and N) at ``centre_en``, measured on the
    WGS84 ellipsoid between the lon/lat pyproj gives for points a pixel apart."""
    from pyproj import Geod, Transformer

    to_ll = Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True)
    e, n, d = centre_en[0], centre_en[1], SCALE / 2
    lon, lat = to_ll.transform([e - d, e + d, e, e], [n, n, n - d, n + d])
    geod = Geod(ellps="WGS84")
    along_e = geod.inv(lon[0], lat[0], lon[1], lat[1])[2]
    along_n = geod.inv(lon[2], lat[2], lon[3], lat[3])[2]
    return math.sqrt(along_e * along_n)


@pytest.mark.parametrize("name", list(GRIDS))
def test_both_readers_report_the_ground_gsd(name: str, tmp_path: Path) -> None:
    epsg, e0, n0 = GRIDS[name]
    w, h = SIZE
    image = np.random.default_rng(3).integers(20, 255, (h, w, 3), dtype=np.uint8)
    tif = write_geotiff(
        tmp_path / f"{name}.tif",
        image,
        scale=(SCALE, SCALE),
        top_left=(e0, n0),
        keys=projected_keys(epsg),
    )
    truth = _ground_px_m(epsg, (e0 + w / 2 * SCALE, n0 - h / 2 * SCALE))
    assert abs(truth / SCALE - 1) > 0.01  # the grid unit is not a ground metre here

    a = build_mbtiles(tif, tmp_path / "r.mbtiles", use_rasterio=True)
    b = build_mbtiles(tif, tmp_path / "t.mbtiles", use_rasterio=False)

    assert (a.reader, b.reader) == ("rasterio", "tifffile")
    assert a.source_gsd_m == pytest.approx(truth, rel=0.005)
    assert b.source_gsd_m == pytest.approx(a.source_gsd_m, rel=1e-9)
    assert a.zooms == b.zooms
    for report in (a, b):
        with MBTilesStore(report.path) as store:
            written = float(store.metadata["c3_source_gsd_m"])
        assert written == pytest.approx(truth, rel=0.005)
