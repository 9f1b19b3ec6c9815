"""The ground tools' geodesy, each fact once: the WGS84 ellipsoid and its metres per degree,
the latitude of a Mercator northing, the linear unit of a projected CRS and the ground GSD of a
north-up grid's pixel scale, the offsets on flat ground (a tangent plane) the simulator and
the import place points with, and where a camera's optical axis meets flat ground
(``axis_ground_point``: the import's look point, and a dataset's truth when no homography
gives it).

The GeoTIFF readers (:mod:`c3_matcher_tools.sim.orthophotos`, :mod:`c3_matcher_tools.tilestore`)
and the projections (:mod:`c3_matcher_tools.tilestore.projection`) build on this module; it
imports nothing of the tools, so every one of them can import it from below. A web-mercator
tile's GSD is the core's (:meth:`c3_matcher.dto.TileId.web_mercator_gsd_m`).
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64
from c3_matcher.camera import rotation_world_from_camera
from c3_matcher.dto import Attitude, CameraCalibration
from c3_matcher.errors import InvalidInputError

__all__ = [
    "LINEAR_UNITS",
    "MERCATOR_EPSG",
    "METRE",
    "WGS84_A",
    "WGS84_E2",
    "WGS84_F",
    "axis_ground_point",
    "flat_offset_latlon",
    "flat_offset_m",
    "ground_gsd_m",
    "m_per_deg",
    "mercator_latitude_deg",
    "point_scale_factor",
    "projected_unit",
    "pyproj_available",
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

LINEAR_UNITS: dict[int, tuple[str, float]] = {
    9001: ("metre", 1.0),
    9002: ("foot", 0.3048),
    9003: ("US survey foot", 1200 / 3937),
    9036: ("kilometre", 1000.0),
}
"""The common linear units by EPSG unit code (a GeoTIFF's ProjLinearUnitsGeoKey): (name, metres
per unit); pyproj knows the others."""
METRE = LINEAR_UNITS[9001]

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


def pyproj_available() -> bool:
    """The ``geo`` extra is installed (pyproj: any EPSG grid, exact) and not switched off by
    ``C3_MATCHER_TOOLS_NO_PYPROJ=1`` (the hand-written fallback, for comparison)."""
    if os.environ.get("C3_MATCHER_TOOLS_NO_PYPROJ") == "1":
        return False
    return importlib.util.find_spec("pyproj") is not None


def projected_unit(
    epsg: int | None, *, unit_code: int | None = None, source: str | Path = "the grid"
) -> tuple[str, float]:
    """(name, metres per unit) of a projected grid's coordinates: the unit its GeoTIFF declares
    (ProjLinearUnitsGeoKey ``unit_code``: :data:`LINEAR_UNITS`, else pyproj's), else the axis
    unit of CRS ``epsg`` (pyproj, :func:`pyproj_available`), else metres (no code, a code PROJ
    does not know, or no pyproj: the hand-written projections and the local tangent plane take
    metres). A declared unit that is not known (a user-defined one) is refused naming
    ``source``: its ground pixel size cannot be measured."""
    if unit_code is not None:
        unit = LINEAR_UNITS.get(unit_code) or _pyproj_unit(unit_code)
        if unit is None:
            raise InvalidInputError(
                "geotiff",
                f"{source}: its coordinates are in linear unit {unit_code} (ProjLinearUnitsGeoKey)"
                ", not an EPSG unit the tools know, so its ground pixel size cannot be measured",
            )
        return unit
    if epsg is None or not pyproj_available():
        return METRE
    return _crs_axis_unit(int(epsg))


def _pyproj_unit(unit_code: int) -> tuple[str, float] | None:
    """(name, metres per unit) of EPSG linear unit ``unit_code`` in PROJ's database, or None."""
    if not pyproj_available():
        return None
    from pyproj.database import get_units_map

    for name, unit in get_units_map(auth_name="EPSG", category="linear").items():
        if unit.code == str(unit_code):
            return str(name), float(unit.conv_factor)
    return None


@functools.lru_cache(maxsize=32)
def _crs_axis_unit(epsg: int) -> tuple[str, float]:
    """(name, metres per unit) of projected CRS ``epsg``'s first axis (pyproj); metres for a
    code PROJ does not know or a CRS that is not projected."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_epsg(epsg)
    except CRSError:
        return METRE
    if not crs.is_projected or not crs.axis_info:
        return METRE
    axis = crs.axis_info[0]
    return str(axis.unit_name), float(axis.unit_conversion_factor)


def ground_gsd_m(
    scale_x: float,
    scale_y: float,
    lat_deg: float,
    *,
    geographic: bool,
    epsg: int | None,
    unit_m: float = 1.0,
    lon_deg: float | None = None,
) -> float:
    """The ground GSD (m/px, geometric mean of x and y) of a north-up grid with pixel scale
    (``scale_x``, ``scale_y``) centred at latitude ``lat_deg`` (and longitude ``lon_deg``):
    degrees (``geographic``) converted on the WGS84 ellipsoid there; projected scales in their
    CRS's linear unit, ``unit_m`` metres each (US feet: 0.3048006, :func:`projected_unit`), then
    divided by the projection's scale factor there: Mercator scales (:data:`MERCATOR_EPSG`) by
    formula, any other CRS ``epsg`` given ``lon_deg`` by :func:`point_scale_factor` (pyproj:
    1.045 for PDC Mercator at 17 S, 0.984 for polar stereographic at 77.7 S, 0.9996 for UTM on
    its central meridian); without a longitude or pyproj as they are."""
    lat = math.radians(lat_deg)
    s2 = math.sin(lat) ** 2
    if geographic:
        m_lon, m_lat = m_per_deg(lat_deg)
        return math.sqrt(scale_x * m_lon * scale_y * m_lat)
    gsd = math.sqrt(scale_x * scale_y) * unit_m
    ellipsoidal = MERCATOR_EPSG.get(epsg) if epsg is not None else None
    if ellipsoidal is True:
        gsd /= math.sqrt(1 - WGS84_E2 * s2) / math.cos(lat)
    elif ellipsoidal is False:
        gsd *= math.cos(lat)
    elif epsg is not None and lon_deg is not None:
        gsd /= point_scale_factor(int(epsg), lon_deg, lat_deg)
    return gsd


def point_scale_factor(epsg: int, lon_deg: float, lat_deg: float) -> float:
    """Projected CRS ``epsg``'s point scale factor at (``lon_deg``, ``lat_deg``): grid length
    over ground length, the square root of its areal scale (a conformal grid's scale in every
    direction), through pyproj (:func:`pyproj_available`); 1 without pyproj, for a code PROJ does
    not know, a CRS that is not projected or a point outside its domain."""
    proj = _scale_proj(int(epsg)) if pyproj_available() else None
    if proj is None:
        return 1.0
    areal = float(proj.get_factors(lon_deg, lat_deg).areal_scale)
    return math.sqrt(areal) if math.isfinite(areal) and areal > 0 else 1.0


@functools.lru_cache(maxsize=32)
def _scale_proj(epsg: int) -> Any:
    """pyproj's ``Proj`` of projected CRS ``epsg`` (its scale factors), or None."""
    from pyproj import CRS, Proj
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_epsg(epsg)
    except CRSError:
        return None
    return Proj(crs) if crs.is_projected else None


def flat_offset_latlon(
    lat_deg: float, lon_deg: float, north_m: float, east_m: float
) -> tuple[float, float]:
    """(lat, lon) degrees of the point ``north_m`` north and ``east_m`` east of (``lat_deg``,
    ``lon_deg``) on the ground plane tangent there (flat ground under a camera), on the WGS84
    ellipsoid (:func:`m_per_deg`): the north step at the start's metres per degree, the east
    step at those of the latitude it reaches (a parallel nears the axis poleward), and the
    east step's drift off its parallel towards the equator (a straight line east does not
    follow the curving parallel). Within 1 mm of the geodesic at 1 km up to 84 deg (a degree of
    latitude is 110.57 km at the equator, 111.69 km at the poles: one scale is metres off)."""
    m_lon, m_lat = m_per_deg(lat_deg)
    lat = lat_deg + north_m / m_lat
    lon = lon_deg + east_m / m_per_deg(lat)[0]
    return lat - _drift_m(lat_deg, m_lon, east_m) / m_lat, lon


def _drift_m(lat_deg: float, m_lon: float, east_m: float) -> float:
    """How far (m) towards the equator a straight line ``east_m`` long leaves the parallel of
    ``lat_deg`` (``m_lon`` metres per degree of longitude there): the parallel's geodesic
    curvature tan(lat) / N times half the square of the length."""
    return east_m * east_m * math.sin(math.radians(lat_deg)) * math.radians(1) / (2 * m_lon)


_INVERSE_STEPS = 3


def flat_offset_m(
    lat_deg: float, lon_deg: float, to_lat_deg: float, to_lon_deg: float
) -> tuple[float, float]:
    """(north, east) metres from (``lat_deg``, ``lon_deg``) to (``to_lat_deg``, ``to_lon_deg``)
    on the same tangent plane: the inverse of :func:`flat_offset_latlon` (a fixed point, its
    drift a correction of parts per million at these lengths, settled in a few steps)."""
    m_lon, m_lat = m_per_deg(lat_deg)
    d_lon = to_lon_deg - lon_deg
    reached, east = to_lat_deg, d_lon * m_per_deg(to_lat_deg)[0]
    for _ in range(_INVERSE_STEPS):
        reached = to_lat_deg + _drift_m(lat_deg, m_lon, east) / m_lat
        east = d_lon * m_per_deg(reached)[0]
    return (reached - lat_deg) * m_lat, east


def axis_ground_point(
    lat: float, lon: float, height_m: float, attitude: Attitude, calibration: CameraCalibration
) -> tuple[float, float] | None:
    """(lat, lon) where the optical axis of a camera at (``lat``, ``lon``), ``height_m`` above
    flat ground with ``attitude``, meets the ground: where the frame's principal point looks,
    the point the matcher's frame centre estimates. None when the axis is about 78 deg off nadir
    or worse (it meets the ground far off, or never: the point means nothing)."""
    axis = rotation_world_from_camera(attitude, calibration) @ np.array([0.0, 0.0, 1.0])
    north, east, down = (float(v) for v in axis)
    if down < 0.2:
        return None
    return flat_offset_latlon(lat, lon, height_m * north / down, height_m * east / down)
