"""The ``geo`` extra (pyproj) against the hand-written fallback on the shipped orthophotos:
LV95 (EPSG:2056) sheets are exact with pyproj where a local tangent plane at the sheet centre
is off by about 3-4 m at the corners; the hand-written UTM (Kruger series) agrees with pyproj to
millimetres on the NAIP sheet."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.georef import haversine_m
from c3_matcher_tools.tilestore.geo import read_geotiff_grid
from c3_matcher_tools.tilestore.projection import Projection

REPO = Path(__file__).resolve().parents[3]
ORTHO = REPO / "data" / "imagery" / "open_orthophotos"
NAIP = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"


def _corners(w: int, h: int) -> np.ndarray:
    return np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]])


@pytest.mark.parametrize(
    "name", ["swissimage_zurich_1091-322_00_0p5m.tif", "swissimage_ref-img_0p5m.tif"]
)
def test_lv95_exact_with_pyproj_tangent_plane_off_by_metres(name: str) -> None:
    from pyproj import Transformer

    grid = read_geotiff_grid(ORTHO / name)
    assert grid.epsg == 2056 and grid.projection.kind == "pyproj"
    w, h = grid.size
    px = _corners(w, h)
    exact = grid.px_to_lonlat(px)
    e = grid.origin_e + (px[:, 0] + 0.5) * grid.scale_x
    n = grid.origin_n - (px[:, 1] + 0.5) * grid.scale_y
    lon, lat = Transformer.from_crs("EPSG:2056", "EPSG:4326", always_xy=True).transform(e, n)
    assert haversine_m(exact, np.stack([lon, lat], axis=1)).max() < 1e-3
    back = grid.lonlat_to_px(exact)
    assert np.abs(back - px).max() < 0.01  # pyproj round trip: millimetres
    centre = exact[4]
    ref_en = (grid.origin_e + w / 2 * grid.scale_x, grid.origin_n - h / 2 * grid.scale_y)
    ltp = dataclasses.replace(
        grid,
        projection=Projection(
            "local_tangent_plane", ref_lat=centre[1], ref_lon=centre[0], ref_en=ref_en
        ),
    )
    err = haversine_m(exact[:4], ltp.px_to_lonlat(px[:4]))
    print(f"{name}: tangent plane vs pyproj at the corners, m: {np.round(err, 2)}")
    assert 1.0 < err.max() < 10.0  # the 3.9 m on a Zurich LV95 sheet


def test_handwritten_utm_agrees_with_pyproj(monkeypatch: pytest.MonkeyPatch) -> None:
    exact = read_geotiff_grid(NAIP)
    assert exact.projection.kind == "pyproj"  # NAD83 / UTM 14N: the datum is pyproj's
    monkeypatch.setenv("C3_MATCHER_TOOLS_NO_PYPROJ", "1")
    fallback = read_geotiff_grid(NAIP)
    assert fallback.projection.kind == "utm"
    w, h = exact.size
    err = haversine_m(exact.px_to_lonlat(_corners(w, h)), fallback.px_to_lonlat(_corners(w, h)))
    print(f"NAIP NAD83 UTM 14N: hand-written (as WGS84) vs pyproj, m: {np.round(err, 3)}")
    assert err.max() < 2.0  # NAD83 vs WGS84 in North Dakota: about a metre
