"""The tools' geodesy, each fact once: the Mercator latitude against pyproj, a grid's ground GSD
by CRS kind, the flat-earth offsets, and a GeoTIFF's GSD read through them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pyproj import Geod, Transformer

from c3_matcher.dto import TileId
from c3_matcher_tools.geodesy import (
    WGS84_A,
    flat_offset_latlon,
    flat_offset_m,
    ground_gsd_m,
    mercator_latitude_deg,
)
from c3_matcher_tools.sim.orthophotos import geotiff_gsd_m
from c3_matcher_tools.tilestore.geo import zoom_for_gsd

LATS = np.array([-80.0, -47.3, -14.6, 0.0, 14.6, 47.0, 84.9])


@pytest.mark.parametrize(("epsg", "ellipsoidal"), [(3395, True), (3857, False)])
def test_mercator_latitude_matches_pyproj(epsg: int, ellipsoidal: bool) -> None:
    to_merc = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
    _e, north = to_merc.transform(np.zeros_like(LATS), LATS)
    lat = mercator_latitude_deg(np.asarray(north), ellipsoidal=ellipsoidal)
    assert np.abs(lat - LATS).max() < 1e-9
    assert float(mercator_latitude_deg(float(north[4]), ellipsoidal=ellipsoidal)) == lat[4]


def test_ground_gsd_by_crs_kind() -> None:
    # projected metres are ground metres, whatever the latitude
    assert ground_gsd_m(0.5, 0.5, 47.0, geographic=False, epsg=2056) == 0.5
    assert ground_gsd_m(2.0, 0.5, 47.0, geographic=False, epsg=None) == 1.0
    # web mercator: a pixel of s metres is s cos(lat) on the ground
    assert ground_gsd_m(1.0, 1.0, 60.0, geographic=False, epsg=3857) == pytest.approx(0.5)
    # World Mercator is on the ellipsoid: a hair larger than the sphere's at mid latitudes
    sphere = ground_gsd_m(1.0, 1.0, 47.0, geographic=False, epsg=3857)
    ellipsoid = ground_gsd_m(1.0, 1.0, 47.0, geographic=False, epsg=3395)
    assert sphere < ellipsoid < sphere * 1.004
    # degrees: one arc second at the equator is 30.71 m (lat, the meridian) by 30.92 m (lon)
    arcsec = 1 / 3600
    at_equator = ground_gsd_m(arcsec, arcsec, 0.0, geographic=True, epsg=4326)
    assert at_equator == pytest.approx(math.sqrt(30.715 * 30.922), abs=0.002)
    # away from the equator the east-west metres shrink with cos(lat)
    at_60 = ground_gsd_m(arcsec, arcsec, 60.0, geographic=True, epsg=4326)
    assert at_60 == pytest.approx(at_equator * math.sqrt(0.5), rel=0.01)


@pytest.mark.parametrize("lat", [0.0, 45.0, 84.0, -84.0])
def test_flat_offsets_land_on_the_geodesic(lat: float) -> None:
    """300 m in every direction on flat ground lands within 5 cm of the ellipsoid's geodesic
    (at the equator a metre per degree of longitude for latitude put it 2 m short), and the
    inverse gives the metres back."""
    geod = Geod(ellps="WGS84")
    for azimuth in range(0, 360, 15):
        north = 300.0 * math.cos(math.radians(azimuth))
        east = 300.0 * math.sin(math.radians(azimuth))
        lon_g, lat_g, _ = geod.fwd(8.0, lat, azimuth, 300.0)
        to_lat, to_lon = flat_offset_latlon(lat, 8.0, north, east)
        assert geod.inv(lon_g, lat_g, to_lon, to_lat)[2] < 0.05, azimuth
        back = flat_offset_m(lat, 8.0, to_lat, to_lon)
        assert back == pytest.approx((north, east), abs=1e-6)


def test_flat_offsets_and_tile_gsd() -> None:
    lat, lon = flat_offset_latlon(60.0, 8.0, 0.0, 0.0)
    assert (lat, lon) == (60.0, 8.0)
    north, east = flat_offset_m(47.0, 8.0, *flat_offset_latlon(47.0, 8.0, 120.0, -35.0))
    assert north == pytest.approx(120.0) and east == pytest.approx(-35.0)
    # the zoom rule takes the web-mercator GSD from the core: zoom 0 is the equator's 2 pi a / 256
    assert TileId(0, 0.0, 0.0).web_mercator_gsd_m() == 2 * math.pi * WGS84_A / 256
    z = zoom_for_gsd(0.5, 47.0)
    assert TileId(z, 47.0, 0.0).web_mercator_gsd_m() <= 0.5 * 1.05
    assert TileId(z - 1, 47.0, 0.0).web_mercator_gsd_m() > 0.5 * 1.05


def _keys(*pairs: tuple[int, int]) -> tuple[int, ...]:
    """A GeoKeyDirectory (tag 34735) of inline keys."""
    out = [1, 1, 0, len(pairs)]
    for key, value in pairs:
        out += [key, 0, 1, value]
    return tuple(out)


def test_geotiff_gsd_needs_a_tie_point_for_degrees_and_mercator() -> None:
    merc = {33550: (0.1, 0.1, 0.0), 34735: _keys((1024, 1), (3072, 3395))}
    utm = {33550: (0.5, 0.5, 0.0), 34735: _keys((1024, 1), (3072, 32614))}
    assert geotiff_gsd_m(merc, 100) is None  # no latitude to take the scale factor at
    assert geotiff_gsd_m(utm, 100) == 0.5  # projected metres need none
    _e, north = Transformer.from_crs("EPSG:4326", "EPSG:3395", always_xy=True).transform(0, 14.6)
    tied = {**merc, 33922: (0.0, 50.0, 0.0, 0.0, north, 0.0)}  # tie point at the centre row
    gsd = geotiff_gsd_m(tied, 100)
    assert gsd == pytest.approx(ground_gsd_m(0.1, 0.1, 14.6, geographic=False, epsg=3395))
    assert gsd == pytest.approx(0.1 * math.cos(math.radians(14.6)), rel=1e-3)
