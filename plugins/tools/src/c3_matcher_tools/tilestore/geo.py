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

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64
from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import (
    MERCATOR_MAX_LAT,
    TILE_PX,
    lonlat_to_world_px,
    world_px_to_lonlat,
)
from c3_matcher_tools.geodesy import projected_unit
from c3_matcher_tools.geotiff import (
    GEOGRAPHIC_CRS_KEY,
    MODEL_TYPE_KEY,
    PROJ_LINEAR_UNITS_KEY,
    PROJECTED_CRS_KEY,
    RASTER_TYPE_KEY,
    USER_DEFINED,
    geo_keys,
    grid_tags,
    model_transformation,
    north_up_scale,
    pixel_scale,
    tiepoint,
)
from c3_matcher_tools.tilestore.projection import Projection, wrap_lon

__all__ = [
    "TILE_PX",
    "TM_REACH_M",
    "GeoGrid",
    "check_grid_fits_crs",
    "check_source_gsd",
    "lonlat_to_world_px",
    "read_geotiff_grid",
    "world_px_to_lonlat",
    "zoom_for_gsd",
]

#: how far east or west of its central meridian (metres) a transverse Mercator grid (UTM, and a
#: pyproj CRS of that method beyond its area of use) is read, and a UTM grid across the equator
#: from its zone's hemisphere (a sheet on the equator is in either). National grids use their
#: UTM zone well beyond it: Norway's zone 33 from -66 km (Utvaer, 4.5 E) to 1,115 km E
#: (31.1 E), 615 km either side; Denmark's and Germany's zone 32 to 15 E. The maths stays exact
#: far past this bound (the tools' Kruger series agrees with PROJ to 0.72 mm at 1,000 km and
#: under 1 mm to 4,000 km), so the bound is set by use: coordinates further out (at the equator,
#: a zone and a half beyond the zone's edge) are more likely a wrong CRS than a grid that far
#: from its zone.
TM_REACH_M = 1_000_000.0


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
    A ModelTransformation stands for both tags when it is north-up; a rotated or flipped one is
    refused as not north-up."""
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
    scale, tie = pixel_scale(tags, p), tiepoint(tags, p)
    if scale is None or tie is None:
        scale, tie = _north_up_transformation(tags, p)
    sx, sy = scale
    keys = geo_keys(tags, p)
    point = keys.get(RASTER_TYPE_KEY) == 2  # RasterPixelIsPoint: the tie point is a pixel centre
    i0, j0, e0, n0 = tie[0], tie[1], tie[3], tie[4]
    shift = 0.5 if point else 0.0
    origin_e = e0 - (i0 + shift) * sx
    origin_n = n0 + (j0 + shift) * sy
    epsg = keys.get(PROJECTED_CRS_KEY) or keys.get(GEOGRAPHIC_CRS_KEY)
    epsg = None if epsg == USER_DEFINED else epsg  # given by its parameters: no EPSG code
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


def _north_up_transformation(
    tags: dict[int, Any], source: Path
) -> tuple[tuple[float, float], tuple[float, ...]]:
    """(pixel scale, tie point) of the north-up ModelTransformation in ``tags``; refused when
    there is none (no georeference) or when it rotates, shears or flips the grid
    (:func:`~c3_matcher_tools.geotiff.north_up_scale`)."""
    matrix = model_transformation(tags, source)
    if matrix is None:
        raise InvalidInputError(
            "geotiff",
            f"{source}: no georeference (no ModelPixelScale/ModelTiepoint or "
            "ModelTransformation tags)",
        )
    return north_up_scale(matrix, source), (0.0, 0.0, 0.0, matrix[2], matrix[5], 0.0)


_MERCATOR_MAX_M = 20_048_966.2  # web-mercator northing at lat 85.06 deg (the tiles' limit)
_UTM_FALSE_EASTING_M = 500_000.0
_UTM_SOUTH_FALSE_NORTHING_M = 10_000_000.0  # a southern zone's northing at the equator


def _utm_bounds(south: bool) -> tuple[str, float, float, float, float]:
    """:func:`_crs_bounds` of a UTM zone: :data:`TM_REACH_M` either side of its meridian, and
    from its pole to as far across the equator (a sheet on the equator is in either zone: a
    northern zone's northings go negative south of it, a southern zone's past 1e7 north of it)."""
    e_lo, e_hi = _UTM_FALSE_EASTING_M - TM_REACH_M, _UTM_FALSE_EASTING_M + TM_REACH_M
    if south:
        n_lo, n_hi = 0.0, _UTM_SOUTH_FALSE_NORTHING_M + TM_REACH_M
    else:
        n_lo, n_hi = -TM_REACH_M, _UTM_SOUTH_FALSE_NORTHING_M
    what = (
        f"UTM metres (E {e_lo:,.0f}..{e_hi:,.0f}, N {n_lo:,.0f}..{n_hi:,.0f}: within "
        f"{TM_REACH_M / 1000:,.0f} km of the zone's meridian and of its hemisphere)"
    )
    return what, e_lo, e_hi, n_lo, n_hi


def _crs_bounds(projection: Projection) -> tuple[str, float, float, float, float] | None:
    """(what the coordinates are, E min, E max, N min, N max) a grid of ``projection`` can hold,
    or None when there is no fixed range (local tangent plane, pyproj: checked in lon/lat)."""
    if projection.kind == "geographic":
        return "degrees (lon -180..180, lat -90..90)", -180.0, 180.0, -90.0, 90.0
    if projection.kind == "utm":
        return _utm_bounds(projection.south)
    if projection.kind in ("web_mercator", "world_mercator"):
        m = _MERCATOR_MAX_M
        return "mercator metres (|E|, |N| <= 20,048,966)", -m, m, -m, m
    return None


def _extent(grid: GeoGrid) -> tuple[float, float, float, float]:
    """(E west, E east, N south, N north) of the grid's outer pixel edges, in its units."""
    w, h = grid.size
    e0, n1 = grid.origin_e, grid.origin_n
    return e0, e0 + w * grid.scale_x, n1 - h * grid.scale_y, n1


def check_grid_fits_crs(grid: GeoGrid, source: str | Path) -> None:
    """Refuse a grid whose coordinates cannot be its CRS's (metres labelled degrees, a wrong
    EPSG code, a missing scale): its corners must lie in the CRS's range (degrees: lon -180..180,
    lat -90..90; UTM: within :data:`TM_REACH_M` of the zone's meridian and of its hemisphere
    (:func:`_utm_bounds`), and not numbers that look like degrees; mercator: within the world)
    and convert to finite lon/lat (pyproj CRSs: within 2 degrees of the CRS's area of use, which
    may cross the antimeridian, or for a transverse Mercator CRS within its latitudes and
    :data:`TM_REACH_M` of its meridian).
    Coordinates in a unit other than metres (feet) need pyproj: the hand-written projections
    take metres."""
    _check_unit(grid, source)
    e0, e1, n0, n1 = _extent(grid)
    label = f"EPSG:{grid.epsg}" if grid.epsg else "its CRS"
    extent = f"E {e0:,.2f}..{e1:,.2f}, N {n0:,.2f}..{n1:,.2f}"
    bounds = _crs_bounds(grid.projection)
    if bounds is not None:
        what, e_lo, e_hi, n_lo, n_hi = bounds
        degrees = grid.projection.kind != "geographic" and max(abs(e0), abs(e1)) <= 180.0
        degrees = degrees and max(abs(n0), abs(n1)) <= 90.0
        if degrees or not (e_lo <= e0 and e1 <= e_hi and n_lo <= n0 and n1 <= n_hi):
            raise InvalidInputError(
                "geotiff",
                f"{source}: coordinates ({extent}) do not fit {label}, whose coordinates are "
                f"{what}{' (these look like degrees)' if degrees else ''}: is the CRS right?",
            )
    w, h = grid.size
    with np.errstate(all="ignore"):
        corners = grid.px_to_lonlat(
            [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]
        )
    ok = bool(np.isfinite(corners).all() and (np.abs(corners[:, 0]) <= 180).all())
    ok = ok and bool((np.abs(corners[:, 1]) <= 90).all())
    if ok and grid.projection.kind == "pyproj":
        _check_area_of_use(grid, corners, f"{source}: coordinates ({extent})", label)
    if not ok:
        raise InvalidInputError(
            "geotiff",
            f"{source}: coordinates ({extent}) do not convert to a valid latitude/longitude "
            f"in {label}: is the CRS right?",
        )


def _check_area_of_use(grid: GeoGrid, corners: F64, said: str, label: str) -> None:
    """Refuse a pyproj grid whose ``corners`` (lon, lat) lie outside its CRS's area of use
    (:func:`_within_area`) unless it is a transverse Mercator grid within the area's latitudes
    and :data:`TM_REACH_M` of its meridian (a national UTM grid used beyond its zone)."""
    area = _area_of_use(grid.projection.epsg)
    if area is None:
        return
    lon, lat = corners[:, 0], corners[:, 1]
    west, south, east, north = area
    if _within_area(lon, lat, area):
        return
    false_easting = _tm_false_easting_m(grid.projection.epsg)
    if false_easting is not None:
        e0, e1, _n0, _n1 = _extent(grid)
        off = max(abs(e0 * grid.unit_m - false_easting), abs(e1 * grid.unit_m - false_easting))
        if off <= TM_REACH_M and bool(((lat >= south - 2) & (lat <= north + 2)).all()):
            return
    reach = "" if false_easting is None else f" and {TM_REACH_M / 1e3:,.0f} km of its meridian"
    raise InvalidInputError(
        "geotiff",
        f"{said} fall at lon {lon.min():.3f}..{lon.max():.3f}, lat {lat.min():.3f}.."
        f"{lat.max():.3f}, outside {label}'s area of use (lon {west}..{east}, lat {south}.."
        f"{north}){reach}: is the CRS right?",
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


@functools.lru_cache(maxsize=32)
def _tm_false_easting_m(epsg: int) -> float | None:
    """The false easting (metres) of EPSG ``epsg`` when it is a transverse Mercator projection
    (UTM and the national grids of that method), else None."""
    from pyproj import CRS

    operation = CRS.from_epsg(epsg).coordinate_operation
    if operation is None or operation.method_name != "Transverse Mercator":
        return None
    for param in operation.params:
        if param.name == "False easting":
            return float(param.value) * float(param.unit_conversion_factor or 1.0)
    return None


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


def grid_outline_lonlat(grid: GeoGrid, per_edge: int = 64) -> F64:
    """(N, 2) (lon, lat) of points along the grid's outer pixel edges, ``per_edge`` segments a
    side (a grid's straight edge curves in lon/lat: its extreme latitude may lie between two
    corners), longitudes unwrapped around the grid centre's (:func:`wrap_lon`)."""
    w, h = grid.size
    t = np.linspace(0.0, 1.0, per_edge + 1)
    u, v = t * w - 0.5, t * h - 0.5
    top, bottom = np.full_like(t, -0.5), np.full_like(t, h - 0.5)
    left, right = np.full_like(t, -0.5), np.full_like(t, w - 0.5)
    edges = [np.stack(pair, axis=1) for pair in ((u, top), (u, bottom), (left, v), (right, v))]
    lonlat = grid.px_to_lonlat(np.concatenate(edges))
    lonlat[:, 0] = wrap_lon(lonlat[:, 0], grid.centre_lonlat()[0])
    return lonlat


def _pole_inside(grid: GeoGrid) -> float | None:
    """The latitude (90 or -90) of a pole the grid holds, or None: a pole its projection maps to
    one point (a polar stereographic or UTM grid, not a geographic or mercator one) inside it."""
    w, h = grid.size
    for lat in (90.0, -90.0):
        with np.errstate(all="ignore"):
            px = grid.lonlat_to_px([[lon, lat] for lon in (-90.0, 0.0, 90.0, 180.0)])
        if not np.isfinite(px).all() or float(np.ptp(px, axis=0).max()) > 1e-3:
            continue
        if -0.5 <= px[0, 0] <= w - 0.5 and -0.5 <= px[0, 1] <= h - 0.5:
            return lat
    return None


def refuse_off_the_tiles(grid: GeoGrid, outline: F64, source: str | Path) -> None:
    """Refuse, before any tile is planned, a grid that web-mercator tiles cannot hold: one that
    holds a pole (the tiles end at +-85.0511 deg and every longitude meets there) or that lies
    wholly beyond +-85.0511 deg; ``outline`` is :func:`grid_outline_lonlat`'s."""
    limit = MERCATOR_MAX_LAT
    pole = _pole_inside(grid)
    if pole is not None:
        name, side, hemi = ("North", "south", "N") if pole > 0 else ("South", "north", "S")
        raise InvalidInputError(
            "geotiff",
            f"{source}: the orthophoto holds the {name} Pole: web-mercator tiles end at "
            f"{limit:.4f} {hemi} and have none there (every longitude meets at the pole); cut "
            f"the orthophoto to the part {side} of {limit:.2f} {hemi} first",
        )
    lat = outline[:, 1]
    if (lat > limit).all() or (lat < -limit).all():
        side = "north of " if lat.min() > 0 else "south of -"
        raise InvalidInputError(
            "geotiff",
            f"{source}: the orthophoto lies wholly {side}{limit:.4f} deg (lat {lat.min():.4f}.."
            f"{lat.max():.4f}), beyond the web-mercator world: no tile can hold it",
        )


def share_beyond_world(grid: GeoGrid, outline: F64) -> float:
    """The share (0..1) of the grid's pixels beyond the web-mercator world (|lat| > 85.0511
    deg, where no tile is), from at most 512 x 512 evenly spread pixel centres; 0 when its
    ``outline`` (:func:`grid_outline_lonlat`) stays within the world."""
    if (np.abs(outline[:, 1]) <= MERCATOR_MAX_LAT).all():
        return 0.0
    w, h = grid.size
    u, v = np.meshgrid(np.linspace(0, w - 1, min(w, 512)), np.linspace(0, h - 1, min(h, 512)))
    lat = grid.px_to_lonlat(np.stack([u.ravel(), v.ravel()], axis=1))[:, 1]
    return float(np.mean(np.abs(lat) > MERCATOR_MAX_LAT))


def tile_ranges(outline: F64, zoom: int) -> tuple[range, range]:
    """The tile columns and rows at ``zoom`` that cover ``outline`` (lon, lat; longitudes
    unwrapped, so the columns of a grid across 180 deg run past the world's last, 2**zoom - 1,
    and are meant modulo 2**zoom; never more than the world's width), rows within the world."""
    n = 1 << zoom
    world = lonlat_to_world_px(outline, zoom)
    x_lo, y_lo = (np.floor(world.min(axis=0)) // TILE_PX).astype(int)
    x_hi, y_hi = (np.floor(world.max(axis=0)) // TILE_PX).astype(int)
    if x_hi - x_lo + 1 >= n:
        x_lo, x_hi = 0, n - 1
    return range(int(x_lo), int(x_hi) + 1), range(max(int(y_lo), 0), min(int(y_hi), n - 1) + 1)
