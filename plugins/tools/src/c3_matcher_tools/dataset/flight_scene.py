"""What a simulated flight is rendered on (its scene) and the records each frame is planned in."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.dto import Attitude, CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.json_text import loads_json
from c3_matcher.tilestore.handles import TileNotFoundError, stitch
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
    "corner_sums",
    "grid_convergence_deg",
    "grid_units_per_m",
    "ground_px_m",
    "read_scene",
    "store_reference",
    "window_starts",
]


@dataclass(frozen=True)
class Coverage:
    """The store's tiles at its finest zoom, read a window at a time: their bounding box
    (COVERAGE px = WORLD px - ``origin``; ``size`` (w, h) px) and the nodata pixels (all channels
    0, or no tile) of every candidate window on the grid (``window_nodata``: (rows, cols), the
    window at row r, column c has its top-left at COVERAGE px (c, r) x the grid's step; see
    :func:`window_starts`), counted tile by tile when the scene is read, so a render holds one
    tile of the store at a time, never the whole coverage."""

    store: MBTilesStore
    origin: tuple[int, int]
    size: tuple[int, int]
    zoom: int
    window_nodata: NDArray[np.int64]

    def window(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.uint8]:
        """COVERAGE px [x0, x1) x [y0, y1) (inside the bounding box) as uint8 RGB, 0 where no
        tile is."""
        ox, oy = self.origin
        try:
            return stitch(
                self.store, self.zoom, (ox + x0, oy + y0), (x1 - x0, y1 - y0), self.store.name
            )
        except TileNotFoundError:
            return np.zeros((y1 - y0, x1 - x0, 3), np.uint8)


def window_starts(length: int, size: int, step: int) -> NDArray[np.int64]:
    """The first px of every ``size`` px window inside ``length`` px, ``step`` apart from 0."""
    return np.arange(0, max(length - size + 1, 0), step, dtype=np.int64)


def corner_sums(
    integral: NDArray[np.int64],
    rows: tuple[NDArray[np.intp], NDArray[np.intp]],
    cols: tuple[NDArray[np.intp], NDArray[np.intp]],
) -> NDArray[np.int64]:
    """Sums over rows [r0, r1) x columns [c0, c1) of the image whose integral (one more row and
    column than it, 0 first) is ``integral``: ((r0, r1), (c0, c1)) indices, one window per
    (row, column) pair, shape (len(r0), len(c0))."""
    (r0, r1), (c0, c1) = rows, cols
    r0, r1 = r0[:, None], r1[:, None]
    return np.asarray(
        integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0], np.int64
    )


def _coverage(spec: FlightSpec, store: MBTilesStore) -> Coverage:
    """The store's finest zoom: its tiles' bounding box, refused across the antimeridian, and
    the nodata of every candidate window there."""
    zooms = store.zooms()
    if not zooms:
        raise InvalidInputError("store", f"{store.path}: holds no tiles")
    z = zooms[-1]
    keys = list(store.tiles(z))
    xs, ys = [k[0] for k in keys], [k[1] for k in keys]
    _refuse_store_across_antimeridian(store.path, z, xs)
    origin = (min(xs) * TILE_PX, min(ys) * TILE_PX)
    size = ((max(xs) - min(xs) + 1) * TILE_PX, (max(ys) - min(ys) + 1) * TILE_PX)
    nodata = _window_nodata(store, z, origin, size, keys, spec)
    return Coverage(store, origin, size, z, nodata)


def _refuse_store_across_antimeridian(store: Path, zoom: int, columns: list[int]) -> None:
    """Refuse a store whose tiles at ``zoom`` lie on both sides of the 180th meridian (their
    columns closer together around it than across the map): its WORLD px are not continuous."""
    n = 1 << zoom
    cols = np.unique(np.asarray(columns) % n)
    gaps = np.diff(cols)
    if gaps.size and cols[0] + n - cols[-1] < gaps.max():
        i = int(np.argmax(gaps))
        raise InvalidInputError(
            "STORE",
            f"{store}: its tiles at zoom {zoom} lie on both sides of the 180th meridian (the "
            f"antimeridian: columns {cols[i + 1]}..{cols[-1]} west of it, {cols[0]}..{cols[i]} "
            "east); a flight is rendered on one side of it: build the store from the "
            "orthophoto's part on one side",
        )


def _window_nodata(
    store: MBTilesStore,
    zoom: int,
    origin: tuple[int, int],
    size: tuple[int, int],
    keys: list[tuple[int, int]],
    spec: FlightSpec,
) -> NDArray[np.int64]:
    """Nodata px of every ``candidate_size_px`` window on the ``grid_px`` grid of the coverage
    (:class:`Coverage`): each stored tile decoded once and counted in the cells the grid and the
    tile edges cut, the windows summed from the cells."""
    (w, h), win, step = size, spec.candidate_size_px, spec.grid_px
    cuts_x = np.union1d(np.arange(0, w + 1, step), np.arange(0, w + 1, TILE_PX))
    cuts_y = np.union1d(np.arange(0, h + 1, step), np.arange(0, h + 1, TILE_PX))
    cells = np.multiply.outer(np.diff(cuts_y), np.diff(cuts_x)).astype(np.int32)  # no tile
    for x, y in keys:
        tx, ty = x * TILE_PX - origin[0], y * TILE_PX - origin[1]
        cx = np.searchsorted(cuts_x, [tx, tx + TILE_PX])
        cy = np.searchsorted(cuts_y, [ty, ty + TILE_PX])
        try:
            tile = stitch(store, zoom, (x * TILE_PX, y * TILE_PX), (TILE_PX, TILE_PX), store.name)
        except TileNotFoundError:
            continue
        empty = ((tile[:, :, 0] | tile[:, :, 1] | tile[:, :, 2]) == 0).astype(np.int32)
        empty = np.add.reduceat(empty, cuts_y[cy[0] : cy[1]] - ty, axis=0)
        cells[cy[0] : cy[1], cx[0] : cx[1]] = np.add.reduceat(
            empty, cuts_x[cx[0] : cx[1]] - tx, axis=1
        )
    integral = np.zeros((cuts_y.size, cuts_x.size), np.int64)
    integral[1:, 1:] = cells.cumsum(axis=0, dtype=np.int64).cumsum(axis=1)
    xs, ys = window_starts(w, win, step), window_starts(h, win, step)
    rows = (np.searchsorted(cuts_y, ys), np.searchsorted(cuts_y, ys + win))
    return corner_sums(
        integral, rows, (np.searchsorted(cuts_x, xs), np.searchsorted(cuts_x, xs + win))
    )


@dataclass(frozen=True)
class Scene:
    """What every frame of a flight is rendered from and placed on: the frames' orthophoto, its
    grid and its ground GSD (m/px) at the flight centre (the grid's scale there over the
    projection's scale factor: :func:`ground_px_m`), the store's coverage and its m/WORLD px,
    the camera, the centre of the flight (projected metres of the frames' grid) and the grid's
    projected units per ground metre (east, north) there (:func:`grid_units_per_m`)."""

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
    cov = _coverage(spec, store)
    _check_overlap(spec, grid, cov, store.path)
    centre_lon, centre_lat = grid.centre_lonlat()
    m_per_px = TileId(cov.zoom, centre_lat, centre_lon).web_mercator_gsd_m()
    _check_coverage(spec, cov, m_per_px)
    calibration = spec.calibration()
    renderer = NavCameraRenderer(calibration)
    centre_en = _flight_centre(store, grid)
    units_per_m = grid_units_per_m(grid, centre_en)
    gsd = math.sqrt(math.prod(ground_px_m(grid, centre_en)))
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
    across, along = ground_px_m(grid, centre)
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
    (ox, oy), (ex, ey) = cov.origin, (cov.origin[0] + cov.size[0], cov.origin[1] + cov.size[1])
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
    w, h = cov.size
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
    to lon/lat and its length taken on the WGS84 ellipsoid (the shorter way round, across the
    antimeridian too): the projection's scale factor there. 0.9996 for UTM on its central
    meridian, 1.045 for PDC Mercator at 17 S, 0.984 for polar stereographic at 77.7 S, 1 / cos(lat)
    for web mercator (1.47 at 47 N), degrees per metre for a geographic grid."""
    e, n = en
    de, dn = grid.scale_x / 2, grid.scale_y / 2
    lon, lat = grid.projection.to_lonlat([e - de, e + de, e, e], [n, n, n - dn, n + dn])
    m_lon, m_lat = m_per_deg(float(lat.mean()))
    along_e = math.hypot(_lon_step(lon[0], lon[1]) * m_lon, (lat[1] - lat[0]) * m_lat)
    along_n = math.hypot(_lon_step(lon[2], lon[3]) * m_lon, (lat[3] - lat[2]) * m_lat)
    return 2 * de / along_e, 2 * dn / along_n


def _lon_step(lon0: float, lon1: float) -> float:
    """Degrees of longitude from ``lon0`` to ``lon1`` the shorter way round."""
    step = float(lon1 - lon0)
    if step > 180.0:
        return step - 360.0
    return step + 360.0 if step < -180.0 else step


def ground_px_m(grid: GeoGrid, en: tuple[float, float]) -> tuple[float, float]:
    """Ground metres one pixel of ``grid`` spans along its E and its N axis at the projected
    point ``en`` (:func:`grid_units_per_m`)."""
    ue, un = grid_units_per_m(grid, en)
    return grid.scale_x / ue, grid.scale_y / un


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
        built = Projection.from_dict(loads_json(text))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise InvalidInputError(
            str(store), f"unreadable c3_georeference metadata ({exc}): rebuild the store"
        ) from None
    return (built.ref_lat, built.ref_lon) if built.kind == "local_tangent_plane" else None
