"""GeoTIFF grids (ground tooling): a north-up grid read from a GeoTIFF, checked against its CRS.

Conventions. ORTHO px (u, v) are 0-based with the origin at the centre of the top-left pixel,
(x, y) order. A GeoTIFF's grid maps them to projected metres (E, N) through its pixel scale and
tie point (``PixelIsArea``: the tie point is the top-left pixel's CORNER; ``PixelIsPoint``:
its centre). WORLD px (X, Y) are web-mercator pixels of 256-px slippy tiles at a zoom ``z``
(corner convention: the world spans [0, 256 * 2**z) and pixel index i has its centre at
X = i + 0.5; tile (x, y) covers X in [256 x, 256 (x + 1))). Projected metres become WGS84
through the grid's :class:`~c3_matcher_tools.tilestore.projection.Projection`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64
from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px, world_px_to_lonlat
from c3_matcher_tools.geodesy import projected_unit
from c3_matcher_tools.geotiff import (
    GEOGRAPHIC_CRS_KEY,
    MODEL_TYPE_KEY,
    PIXEL_SCALE,
    PROJ_LINEAR_UNITS_KEY,
    PROJECTED_CRS_KEY,
    RASTER_TYPE_KEY,
    TIEPOINT,
    geo_keys,
    grid_tags,
    pixel_scale,
    tiepoint,
)
from c3_matcher_tools.tilestore.projection import Projection

__all__ = [
    "TILE_PX",
    "GeoGrid",
    "check_grid_fits_crs",
    "check_source_gsd",
    "lonlat_to_world_px",
    "read_geotiff_grid",
    "world_px_to_lonlat",
    "zoom_for_gsd",
]


@dataclass(frozen=True)
class GeoGrid:
    """A north-up GeoTIFF grid: ORTHO px (u, v) -> projected coordinates (metres, feet)
    ``E = origin_e + (u + 0.5) * scale_x``, ``N = origin_n - (v + 0.5) * scale_y`` where
    (origin_e, origin_n) is the top-left pixel's corner; ``projection`` converts to WGS84;
    ``size`` (w, h) px; ``epsg`` the file's projected/geographic CRS code (None if absent);
    ``unit_m`` metres per unit of a projected grid's coordinates (0.3048 for feet; 1 for
    degrees, whose ground size :func:`~c3_matcher_tools.geodesy.ground_gsd_m` converts)."""

    origin_e: float
    origin_n: float
    scale_x: float
    scale_y: float
    size: tuple[int, int]
    epsg: int | None
    projection: Projection
    unit_m: float = 1.0

    def px_to_lonlat(self, pts: ArrayLike) -> F64:
        """(N, 2) ORTHO px -> (N, 2) (lon, lat) degrees."""
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        e = self.origin_e + (p[:, 0] + 0.5) * self.scale_x
        n = self.origin_n - (p[:, 1] + 0.5) * self.scale_y
        lon, lat = self.projection.to_lonlat(e, n)
        return np.stack([lon, lat], axis=1)

    def lonlat_to_px(self, lonlat: ArrayLike) -> F64:
        """(N, 2) (lon, lat) degrees -> (N, 2) ORTHO px."""
        q = np.asarray(lonlat, dtype=np.float64).reshape(-1, 2)
        e, n = self.projection.from_lonlat(q[:, 0], q[:, 1])
        return np.stack(
            [(e - self.origin_e) / self.scale_x - 0.5, (self.origin_n - n) / self.scale_y - 0.5],
            axis=1,
        )

    def centre_lonlat(self) -> tuple[float, float]:
        w, h = self.size
        lon, lat = self.px_to_lonlat([[(w - 1) / 2, (h - 1) / 2]])[0]
        return float(lon), float(lat)


def read_geotiff_grid(path: str | Path, *, reference: tuple[float, float] | None = None) -> GeoGrid:
    """Read the north-up grid of a GeoTIFF (ModelPixelScale + ModelTiepoint + GeoKeys) with
    ``tifffile``; ``reference`` (lat, lon) of the image centre is needed for CRSs other than
    UTM / mercator / 4326 (see :class:`~c3_matcher_tools.tilestore.projection.Projection`).
    Rotated grids (ModelTransformation) are refused."""
    import tifffile

    p = Path(path)
    if not p.is_file():
        raise InvalidInputError("geotiff", f"no such file: {p}")
    try:
        with tifffile.TiffFile(str(p)) as tif:
            page = tif.pages.first
            tags = grid_tags(page)
            w, h = int(page.imagewidth), int(page.imagelength)
    except Exception as exc:  # tifffile raises many kinds on a non-TIFF
        raise InvalidInputError(
            "geotiff", f"{p}: no georeference (not a TIFF: {' '.join(str(exc).split())})"
        ) from exc
    if PIXEL_SCALE not in tags or TIEPOINT not in tags:
        raise InvalidInputError(
            "geotiff",
            f"{p}: no georeference (no ModelPixelScale/ModelTiepoint tags: not a north-up GeoTIFF)",
        )
    scale, tie = pixel_scale(tags, p), tiepoint(tags, p)
    assert scale is not None and tie is not None  # both tags are there
    sx, sy = scale
    keys = geo_keys(tags, p)
    point = keys.get(RASTER_TYPE_KEY) == 2  # RasterPixelIsPoint: the tie point is a pixel centre
    i0, j0, e0, n0 = tie[0], tie[1], tie[3], tie[4]
    shift = 0.5 if point else 0.0
    origin_e = e0 - (i0 + shift) * sx
    origin_n = n0 + (j0 + shift) * sy
    epsg = keys.get(PROJECTED_CRS_KEY) or keys.get(GEOGRAPHIC_CRS_KEY)
    unit_m = 1.0
    if keys.get(MODEL_TYPE_KEY) != 2:  # projected: its coordinates' unit (feet or metres)
        code = keys.get(PROJECTED_CRS_KEY)
        unit_m = projected_unit(code, unit_code=keys.get(PROJ_LINEAR_UNITS_KEY), source=p)[1]
    centre_en = (origin_e + w / 2 * sx, origin_n - h / 2 * sy)
    projection = Projection.from_epsg(
        None if epsg is None else int(epsg), reference=reference, ref_en=centre_en, source=p
    )
    grid = GeoGrid(origin_e, origin_n, sx, sy, (w, h), epsg, projection, unit_m)
    check_grid_fits_crs(grid, p)
    return grid


_MERCATOR_MAX_M = 20_048_966.2  # web-mercator northing at lat 85.06 deg (the tiles' limit)


def _crs_bounds(projection: Projection) -> tuple[str, float, float, float, float] | None:
    """(what the coordinates are, E min, E max, N min, N max) a grid of ``projection`` can hold,
    or None when there is no fixed range (local tangent plane, pyproj: checked in lon/lat)."""
    if projection.kind == "geographic":
        return "degrees (lon -180..180, lat -90..90)", -180.0, 180.0, -90.0, 90.0
    if projection.kind == "utm":
        return "UTM metres (E 0..1,000,000, N 0..10,000,000)", 0.0, 1e6, 0.0, 1e7
    if projection.kind in ("web_mercator", "world_mercator"):
        m = _MERCATOR_MAX_M
        return "mercator metres (|E|, |N| <= 20,048,966)", -m, m, -m, m
    return None


def check_grid_fits_crs(grid: GeoGrid, source: str | Path) -> None:
    """Refuse a grid whose coordinates cannot be its CRS's (metres labelled degrees, a wrong
    EPSG code, a missing scale): its corners must lie in the CRS's range (degrees: lon -180..180,
    lat -90..90; UTM: E 0..1e6 m, N 0..1e7 m; mercator: within the world) and convert to finite
    lon/lat (pyproj CRSs: within 2 degrees of the CRS's area of use, which may cross the
    antimeridian). Coordinates in a unit other than metres (feet) need pyproj: the hand-written
    projections take metres."""
    _check_unit(grid, source)
    w, h = grid.size
    e0, e1 = grid.origin_e, grid.origin_e + w * grid.scale_x
    n0, n1 = grid.origin_n - h * grid.scale_y, grid.origin_n
    label = f"EPSG:{grid.epsg}" if grid.epsg else "its CRS"
    extent = f"E {e0:,.2f}..{e1:,.2f}, N {n0:,.2f}..{n1:,.2f}"
    bounds = _crs_bounds(grid.projection)
    if bounds is not None:
        what, e_lo, e_hi, n_lo, n_hi = bounds
        if not (e_lo <= e0 and e1 <= e_hi and n_lo <= n0 and n1 <= n_hi):
            raise InvalidInputError(
                "geotiff",
                f"{source}: coordinates ({extent}) do not fit {label}, whose coordinates are "
                f"{what}: is the CRS right?",
            )
    with np.errstate(all="ignore"):
        corners = grid.px_to_lonlat(
            [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]
        )
    lon, lat = corners[:, 0], corners[:, 1]
    ok = bool(np.isfinite(corners).all() and (np.abs(lon) <= 180).all())
    ok = ok and bool((np.abs(lat) <= 90).all())
    if ok and grid.projection.kind == "pyproj":
        area = _area_of_use(grid.projection.epsg)
        if area is not None:
            west, south, east, north = area
            ok = _within_area(lon, lat, area)
            if not ok:
                raise InvalidInputError(
                    "geotiff",
                    f"{source}: coordinates ({extent}) fall at lon {lon.min():.3f}..{lon.max():.3f}"
                    f", lat {lat.min():.3f}..{lat.max():.3f}, outside {label}'s area of use (lon "
                    f"{west}..{east}, lat {south}..{north}): is the CRS right?",
                )
    if not ok:
        raise InvalidInputError(
            "geotiff",
            f"{source}: coordinates ({extent}) do not convert to a valid latitude/longitude "
            f"in {label}: is the CRS right?",
        )


def _within_area(lon: F64, lat: F64, area: tuple[float, float, float, float]) -> bool:
    """Every (lon, lat) lies within 2 degrees of ``area`` (west, south, east, north) degrees;
    a west bound east of the east bound crosses the antimeridian (EPSG:4269's NAD83 runs from
    167.65 E across 180 to 40.73 W): longitudes are measured eastward from the west bound."""
    west, south, east, north = area
    span = (east - west) % 360.0 or 360.0  # 0: the whole circle (-180..180)
    east_of_west = (lon - west) % 360.0
    lon_ok = (east_of_west <= span + 2) | (east_of_west >= 360.0 - 2)
    lat_ok = (lat >= south - 2) & (lat <= north + 2)
    return bool(lon_ok.all() and lat_ok.all())


def _check_unit(grid: GeoGrid, source: str | Path) -> None:
    """Refuse a grid in a unit other than metres (feet) whose projection is hand-written (UTM,
    mercator, a local tangent plane): those take metres, only pyproj converts the CRS's own."""
    if math.isclose(grid.unit_m, 1.0) or grid.projection.kind in ("pyproj", "geographic"):
        return
    label = f"EPSG:{grid.epsg}" if grid.epsg else "its CRS"
    raise InvalidInputError(
        "geotiff",
        f"{source}: its coordinates are in units of {grid.unit_m:g} m ({label}), but the "
        f"{grid.projection.describe()} projection takes metres: install the geo extra "
        "(pyproj) to convert them exactly",
    )


#: plausible ground GSD of an orthophoto, m/px (a grid outside it has the wrong units)
GSD_RANGE_M = (0.001, 10_000.0)


def check_source_gsd(gsd_m: float, source: str | Path) -> None:
    """Refuse a ground GSD outside :data:`GSD_RANGE_M` (degrees labelled metres and the like)."""
    lo, hi = GSD_RANGE_M
    if not (math.isfinite(gsd_m) and lo <= gsd_m <= hi):
        raise InvalidInputError(
            "geotiff",
            f"{source}: a pixel of {gsd_m:.6g} m on the ground is not plausible for an "
            f"orthophoto ({lo} to {hi:,.0f} m): are the CRS and its units right?",
        )


def _area_of_use(epsg: int) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) degrees where pyproj says EPSG ``epsg`` is used, or None."""
    from pyproj import CRS

    area = CRS.from_epsg(epsg).area_of_use
    return None if area is None else (area.west, area.south, area.east, area.north)


def zoom_for_gsd(gsd_m: float, lat_deg: float) -> int:
    """The default web-mercator zoom for a source of ground GSD ``gsd_m`` at ``lat_deg``: the
    coarsest zoom whose ground GSD is at most the source's (x 1.05, so a source a hair coarser
    than a zoom is not upsampled needlessly), i.e. no source detail is thrown away. (The zoom
    nearest the GSD on a log scale, the old default, picked zoom 14 at 6.5 m/px for the 5 m NAIP
    sheet: a store of 12 tiles on which ``dataset render`` finds no distractors.)"""
    z0 = TileId(0, lat_deg, 0.0).web_mercator_gsd_m()
    return max(0, min(30, math.ceil(math.log2(z0 / (gsd_m * 1.05)))))
