"""What a simulated flight is rendered on (its scene) and the records each frame is planned in."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.handles import stitch
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.format import FrameRecord
from c3_matcher_tools.geodesy import m_per_deg
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.sim.render import NavCameraRenderer, RenderedFrame
from c3_matcher_tools.tilestore.geo import (
    TILE_PX,
    GeoGrid,
    read_geotiff_grid,
    world_px_to_lonlat,
)
from c3_matcher_tools.tilestore.projection import Projection

__all__ = [
    "Coverage",
    "Footprint",
    "PlannedFrame",
    "Scene",
    "Shot",
    "grid_convergence_deg",
    "grid_units_per_m",
    "read_scene",
    "store_reference",
]


@dataclass(frozen=True)
class Coverage:
    """The store's whole coverage at one zoom as one image: COVERAGE px = WORLD px - origin."""

    image: NDArray[np.uint8]
    origin: tuple[int, int]
    zoom: int


def _coverage(store: MBTilesStore) -> Coverage:
    zooms = store.zooms()
    if not zooms:
        raise InvalidInputError("store", f"{store.path}: holds no tiles")
    z = zooms[-1]
    keys = list(store.tiles(z))
    xs, ys = [k[0] for k in keys], [k[1] for k in keys]
    origin = (min(xs) * TILE_PX, min(ys) * TILE_PX)
    size = ((max(xs) - min(xs) + 1) * TILE_PX, (max(ys) - min(ys) + 1) * TILE_PX)
    return Coverage(stitch(store, z, origin, size, store.name), origin, z)


@dataclass(frozen=True)
class Scene:
    """What every frame of a flight is rendered from and placed on: the frames' orthophoto, its
    grid and GSD (m/px), the store's coverage and its m/WORLD px, the camera, the centre of the
    flight (projected metres of the frames' grid) and the grid's projected units per ground metre
    (east, north) there (:func:`grid_units_per_m`)."""

    grid: GeoGrid
    rgb: NDArray[np.uint8]
    gsd: float
    cov: Coverage
    m_per_px: float
    calibration: CameraCalibration
    renderer: NavCameraRenderer
    centre_en: tuple[float, float]
    units_per_m: tuple[float, float]


@dataclass(frozen=True)
class Shot:
    """One frame rendered along the trajectory: its index, heading (deg), attitude, the ORTHO px
    below the camera, and the rendered frame."""

    index: int
    heading: float
    attitude: Attitude
    nadir: tuple[float, float]
    frame: RenderedFrame


@dataclass(frozen=True)
class Footprint:
    """A frame's ground footprint (WORLD px of the store's zoom), its centre, and the top-left
    WORLD px of the true candidate window that holds it."""

    world: F64
    centre: F64
    true_origin: tuple[int, int]


@dataclass(frozen=True)
class PlannedFrame:
    """One frame planned: its record, its JPEG bytes, and the homography fit residual (px) of
    each of its candidates."""

    record: FrameRecord
    jpeg: bytes
    fits: tuple[float, ...]


def read_scene(spec: FlightSpec, store: MBTilesStore) -> Scene:
    """Read the frames' orthophoto, its grid and the store's coverage; set up the camera."""
    reference = spec.reference_latlon or store_reference(store.metadata, store.path)
    grid = read_geotiff_grid(spec.frames_geotiff, reference=reference)
    _check_square_pixels(spec, grid)
    photo = load_orthophoto(spec.frames_geotiff)
    gsd = photo.gsd_m or math.sqrt(grid.scale_x * grid.scale_y)
    cov = _coverage(store)
    _check_overlap(spec, grid, cov, store.path)
    centre_lon, centre_lat = grid.centre_lonlat()
    m_per_px = TileId(cov.zoom, centre_lat, centre_lon).web_mercator_gsd_m()
    _check_coverage(spec, cov, m_per_px)
    calibration = spec.calibration()
    renderer = NavCameraRenderer(calibration)
    centre_en = _flight_centre(store, grid)
    units_per_m = grid_units_per_m(grid, centre_en)
    return Scene(grid, photo.rgb, gsd, cov, m_per_px, calibration, renderer, centre_en, units_per_m)


SQUARE_PIXEL_TOLERANCE = 0.005
"""How far a frames orthophoto's pixel may be from square on the ground (0.5 %): a projected
grid's pixels are square to its scale error (< 0.1 % for UTM and national grids); a pixel of
equal degrees is cos(latitude) as wide as it is high, 0.5 % narrower 6 deg from the equator."""


def _check_square_pixels(spec: FlightSpec, grid: GeoGrid) -> None:
    """Refuse an orthophoto whose pixels are not square on the ground at its centre (a grid of
    equal degrees): the renderer takes each pixel as a square of one GSD, so its frames would
    be stretched east-west while their height and attitude describe an upright camera."""
    w, h = grid.size
    centre = (grid.origin_e + w / 2 * grid.scale_x, grid.origin_n - h / 2 * grid.scale_y)
    ue, un = grid_units_per_m(grid, centre)
    across, along = grid.scale_x / ue, grid.scale_y / un  # ground m per px, east and north
    if abs(across / along - 1.0) > SQUARE_PIXEL_TOLERANCE:
        raise InvalidInputError(
            "frames_geotiff",
            f"{spec.frames_geotiff}: its pixels are {across:.3g} m wide and {along:.3g} m high "
            "on the ground (a grid of equal degrees?); frames are rendered from square pixels: "
            "reproject it to a projected CRS first (UTM, or the national grid)",
        )


def _check_overlap(spec: FlightSpec, grid: GeoGrid, cov: Coverage, store: Path) -> None:
    """Refuse frames whose orthophoto and the store's tiles show different places (their
    latitude and longitude spans named) before any other advice about the store's size."""
    w, h = grid.size
    photo = grid.px_to_lonlat([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    rows, cols = cov.image.shape[:2]
    (ox, oy), (ex, ey) = cov.origin, (cov.origin[0] + cols, cov.origin[1] + rows)
    tiles = world_px_to_lonlat([[ox, oy], [ex, ey]], cov.zoom)
    p_lat0, p_lat1, p_lon0, p_lon1 = _span(photo)
    t_lat0, t_lat1, t_lon0, t_lon1 = _span(tiles)
    if p_lat1 < t_lat0 or t_lat1 < p_lat0 or p_lon1 < t_lon0 or t_lon1 < p_lon0:
        raise InvalidInputError(
            "frames_geotiff",
            f"{spec.frames_geotiff} (lat {p_lat0:.4f}..{p_lat1:.4f}, lon {p_lon0:.4f}.."
            f"{p_lon1:.4f}) and the store {store.name} (lat {t_lat0:.4f}..{t_lat1:.4f}, lon "
            f"{t_lon0:.4f}..{t_lon1:.4f}) do not overlap: render from an orthophoto of the "
            "store's place",
        )


def _span(lonlat: F64) -> tuple[float, float, float, float]:
    """(lat min, lat max, lon min, lon max) of (N, 2) (lon, lat) points."""
    lon, lat = lonlat[:, 0], lonlat[:, 1]
    return float(lat.min()), float(lat.max()), float(lon.min()), float(lon.max())


def _check_coverage(spec: FlightSpec, cov: Coverage, m_per_px: float) -> None:
    """Refuse a store too small for a candidate window plus distractors at the requested
    distance before any frame is rendered (names the command-line options)."""
    h, w = cov.image.shape[:2]
    size = spec.candidate_size_px
    need = size + spec.min_distractor_distance_m / m_per_px
    if w < need and h < need:
        raise InvalidInputError(
            "--candidate-size",
            f"the store covers {w}x{h} px at zoom {cov.zoom} ({m_per_px:.2f} m/px), too small "
            f"for a {size} px candidate plus distractors {spec.min_distractor_distance_m:.0f} m "
            "away: lower --candidate-size or --min-distractor-distance, or build the store at "
            f"a finer zoom (tiles build --zoom {cov.zoom + 1})",
        )


def _flight_centre(store: MBTilesStore, grid: GeoGrid) -> tuple[float, float]:
    """Projected metres (frames grid) of the store's ``center`` (a fixed ground point, so
    flights rendered from different dates of the same ground fly the same path), else of the
    frames orthophoto's centre."""
    centre = store.metadata.get("center", "")
    try:
        lon, lat = (float(v) for v in centre.split(",")[:2])
    except ValueError:
        lon, lat = grid.centre_lonlat()
    e, n = grid.projection.from_lonlat([lon], [lat])
    return float(e[0]), float(n[0])


def grid_units_per_m(grid: GeoGrid, en: tuple[float, float]) -> tuple[float, float]:
    """The projected units of ``grid`` per ground metre along its E and its N axis at the
    projected point ``en``, measured through its projection: a one-pixel step each way converted
    to lon/lat and its length taken on the WGS84 ellipsoid. About 1 for UTM and national grids
    (their scale error, < 0.1 %), 1 / cos(lat) for web mercator (1.47 at 47 N), degrees per
    metre for a geographic grid."""
    e, n = en
    de, dn = grid.scale_x / 2, grid.scale_y / 2
    lon, lat = grid.projection.to_lonlat([e - de, e + de, e, e], [n, n, n - dn, n + dn])
    m_lon, m_lat = m_per_deg(float(lat.mean()))
    along_e = math.hypot((lon[1] - lon[0]) * m_lon, (lat[1] - lat[0]) * m_lat)
    along_n = math.hypot((lon[3] - lon[2]) * m_lon, (lat[3] - lat[2]) * m_lat)
    return 2 * de / along_e, 2 * dn / along_n


def grid_convergence_deg(grid: GeoGrid, px: tuple[float, float]) -> float:
    """The grid convergence (deg) at ORTHO px ``px``: the angle clockwise from true north to
    the grid's north (up, -v), so a bearing measured from grid north plus it is the bearing from
    true north. Measured through the grid's projection: a step of about 1 m north along the
    meridian through ``px`` mapped back to ORTHO px (UTM: about +(lon - central meridian) *
    sin(lat), positive east of the central meridian in the northern hemisphere; 0 for
    mercator and geographic grids)."""
    lon, lat = grid.px_to_lonlat([px])[0]
    d = 1e-5  # degrees of latitude: about 1.1 m
    south, north = grid.lonlat_to_px([[lon, lat - d], [lon, lat + d]])
    du, dv = north - south
    return -math.degrees(math.atan2(du, -dv))


def store_reference(metadata: Mapping[str, str], store: Path) -> tuple[float, float] | None:
    """The (lat, lon) reference a tile store was built around when its GeoTIFF's grid was
    treated as a local tangent plane (``c3_georeference``, written by ``tiles build``), so
    frames rendered from the same grid land on its tiles; None for any other store.
    ``InvalidInputError`` naming the store when that metadata cannot be read."""
    text = metadata.get("c3_georeference")
    if text is None:
        return None
    try:
        built = Projection.from_dict(json.loads(text))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise InvalidInputError(
            str(store), f"unreadable c3_georeference metadata ({exc}): rebuild the store"
        ) from None
    return (built.ref_lat, built.ref_lon) if built.kind == "local_tangent_plane" else None
