"""The ground tools' geodesy, each fact once: the WGS84 ellipsoid and its metres per degree,
the latitude of a Mercator northing, the ground GSD of a north-up grid's pixel scale, and the
flat-earth offsets the simulator and the candidate proposer place points with.

The GeoTIFF readers (:mod:`c3_matcher_tools.sim.orthophotos`, :mod:`c3_matcher_tools.tilestore`)
and the projections (:mod:`c3_matcher_tools.tilestore.projection`) build on this module; it
imports nothing of the tools, so every one of them can import it from below. A web-mercator
tile's GSD is the core's (:meth:`c3_matcher.dto.TileId.web_mercator_gsd_m`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64

__all__ = [
    "FLAT_M_PER_DEG_LAT",
    "MERCATOR_EPSG",
    "WGS84_A",
    "WGS84_E2",
    "WGS84_F",
    "flat_offset_latlon",
    "flat_offset_m",
    "ground_gsd_m",
    "m_per_deg",
    "mercator_latitude_deg",
]

WGS84_A = 6378137.0
"""The WGS84 ellipsoid's semi-major axis (m)."""
WGS84_F = 1 / 298.257223563
"""The WGS84 ellipsoid's flattening."""
WGS84_E2 = WGS84_F * (2 - WGS84_F)
"""The WGS84 ellipsoid's first eccentricity squared."""

MERCATOR_EPSG: dict[int, bool] = {3395: True, 3857: False, 900913: False, 3785: False}
"""The Mercator CRSs by EPSG code, each True when it is on the ellipsoid (World Mercator) and
False on the sphere (web mercator and its old codes)."""

FLAT_M_PER_DEG_LAT = 111_320.0
"""Metres per degree of latitude on the flat earth the simulator and the candidate proposer
place points on (offsets of a few hundred metres: the ellipsoid's 1 % over latitude is below
what either needs)."""

_MERCATOR_ITERATIONS = 12


def mercator_latitude_deg(northing_m: ArrayLike, *, ellipsoidal: bool) -> F64:
    """The latitude (deg) of Mercator northing ``northing_m`` (m): on the WGS84 ellipsoid
    (EPSG:3395, a fixed-point iteration that has converged well before its last step) or on the
    sphere of radius :data:`WGS84_A` (web mercator)."""
    t = np.exp(-np.asarray(northing_m, dtype=np.float64) / WGS84_A)
    phi = np.pi / 2 - 2 * np.arctan(t)
    if ellipsoidal:
        e1 = math.sqrt(WGS84_E2)
        for _ in range(_MERCATOR_ITERATIONS):
            es = e1 * np.sin(phi)
            phi = np.pi / 2 - 2 * np.arctan(t * ((1 - es) / (1 + es)) ** (e1 / 2))
    degrees: F64 = np.degrees(phi)
    return degrees


def m_per_deg(lat_deg: float) -> tuple[float, float]:
    """(east, north) ground metres per degree of longitude and of latitude at latitude
    ``lat_deg`` on the WGS84 ellipsoid (its prime-vertical and meridional radii): the exact
    length of a small step in lon/lat."""
    lat = math.radians(lat_deg)
    w2 = 1 - WGS84_E2 * math.sin(lat) ** 2
    m_lon = math.radians(1) * WGS84_A * math.cos(lat) / math.sqrt(w2)
    m_lat = math.radians(1) * WGS84_A * (1 - WGS84_E2) / w2**1.5
    return m_lon, m_lat


def ground_gsd_m(
    scale_x: float, scale_y: float, lat_deg: float, *, geographic: bool, epsg: int | None
) -> float:
    """The ground GSD (m/px, geometric mean of x and y) of a north-up grid with pixel scale
    (``scale_x``, ``scale_y``) centred at latitude ``lat_deg``: degrees (``geographic``)
    converted on the WGS84 ellipsoid there; Mercator scales (:data:`MERCATOR_EPSG`) divided by
    their scale factor there; projected metres as they are (UTM's and the national grids' scale
    error, < 0.1 %, is ignored)."""
    lat = math.radians(lat_deg)
    s2 = math.sin(lat) ** 2
    if geographic:
        m_lon, m_lat = m_per_deg(lat_deg)
        return math.sqrt(scale_x * m_lon * scale_y * m_lat)
    gsd = math.sqrt(scale_x * scale_y)
    ellipsoidal = MERCATOR_EPSG.get(epsg) if epsg is not None else None
    if ellipsoidal is True:
        gsd /= math.sqrt(1 - WGS84_E2 * s2) / math.cos(lat)
    elif ellipsoidal is False:
        gsd *= math.cos(lat)
    return gsd


def flat_offset_latlon(
    lat_deg: float, lon_deg: float, north_m: float, east_m: float
) -> tuple[float, float]:
    """(lat, lon) degrees ``north_m`` north and ``east_m`` east of (``lat_deg``, ``lon_deg``) on
    the flat earth of :data:`FLAT_M_PER_DEG_LAT`, the east scale taken at ``lat_deg``."""
    lat = lat_deg + north_m / FLAT_M_PER_DEG_LAT
    lon = lon_deg + east_m / (FLAT_M_PER_DEG_LAT * math.cos(math.radians(lat_deg)))
    return lat, lon


def flat_offset_m(
    lat_deg: float, lon_deg: float, to_lat_deg: float, to_lon_deg: float
) -> tuple[float, float]:
    """(north, east) metres from (``lat_deg``, ``lon_deg``) to (``to_lat_deg``, ``to_lon_deg``)
    on the same flat earth (the inverse of :func:`flat_offset_latlon`)."""
    north = (to_lat_deg - lat_deg) * FLAT_M_PER_DEG_LAT
    east = (to_lon_deg - lon_deg) * FLAT_M_PER_DEG_LAT * math.cos(math.radians(lat_deg))
    return north, east
