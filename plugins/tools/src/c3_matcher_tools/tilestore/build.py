"""Build an MBTiles store of 256-px web-mercator tiles from a north-up GeoTIFF orthophoto.

Every tile pixel centre (WORLD px) is converted to (lon, lat), then to the GeoTIFF's projected
metres and ORTHO px (:mod:`c3_matcher.tilestore.geo`: exact for UTM / mercator / geographic
grids, a documented local tangent plane otherwise), and sampled bilinearly
(``cv2.remap``; the orthophoto is first area-downscaled when the tiles are >= 1.15x coarser).
Pixels outside the orthophoto or on its nodata (all bands 0) are 0 (nodata); tiles with no data
are not stored. The zoom defaults to the coarsest whose ground GSD at the image centre is at most
the orthophoto's (:func:`c3_matcher_tools.tilestore.geo.zoom_for_gsd`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.tilestore.geo import (
    TILE_PX,
    GeoGrid,
    lonlat_to_world_px,
    read_geotiff_grid,
    world_px_to_lonlat,
    zoom_for_gsd,
)
from c3_matcher_tools.tilestore.writer import MBTilesWriter

__all__ = ["BuildReport", "build_mbtiles", "render_tile"]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class BuildReport:
    """What ``build_mbtiles`` wrote: ``tiles`` stored (of ``candidates`` in the bounds)."""

    path: Path
    zoom: int
    tiles: int
    candidates: int
    tile_gsd_m: float
    source_gsd_m: float
    georeference: str
    bytes: int


def render_tile(
    ortho: NDArray[np.uint8],
    valid: NDArray[np.uint8],
    grid: GeoGrid,
    zoom: int,
    x: int,
    y: int,
    scale: float = 1.0,
) -> NDArray[np.uint8] | None:
    """Tile (zoom, x, y) resampled from ``ortho`` (uint8 RGB, possibly pre-scaled by ``scale``
    relative to ``grid``'s pixels) with nodata 0, or None when it holds no data."""
    i = np.arange(TILE_PX, dtype=np.float64) + 0.5
    wx, wy = np.meshgrid(x * TILE_PX + i, y * TILE_PX + i)
    lonlat = world_px_to_lonlat(np.stack([wx.ravel(), wy.ravel()], axis=1), zoom)
    uv = grid.lonlat_to_px(lonlat)
    map_x = ((uv[:, 0] + 0.5) * scale - 0.5).reshape(TILE_PX, TILE_PX).astype(np.float32)
    map_y = ((uv[:, 1] + 0.5) * scale - 0.5).reshape(TILE_PX, TILE_PX).astype(np.float32)
    mask = cv2.remap(valid, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    if not mask.any():
        return None
    img = cv2.remap(ortho, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    img[mask == 0] = 0
    return np.asarray(img, dtype=np.uint8)


def build_mbtiles(
    geotiff: str | Path,
    out: str | Path,
    *,
    zoom: int | None = None,
    tile_format: str = "png",
    jpeg_quality: int = 90,
    reference: tuple[float, float] | None = None,
    attribution: str = "",
    overwrite: bool = False,
    progress: Progress | None = None,
) -> BuildReport:
    """Write ``out`` (MBTiles) from ``geotiff``; ``reference`` (lat, lon) of the image centre is
    needed for grids that are not UTM / mercator / geographic (local tangent plane). ``progress``
    is called with (done, total) after every tile."""
    if tile_format not in ("png", "jpg"):
        raise InvalidInputError("format", f"expected png or jpg, got {tile_format!r}")
    grid = read_geotiff_grid(geotiff, reference=reference)
    photo = load_orthophoto(geotiff)
    if photo.size != grid.size:
        raise InvalidInputError(
            "geotiff", f"{geotiff}: pixel size {photo.size} != grid {grid.size}"
        )
    gsd = math.sqrt(grid.scale_x * grid.scale_y) if photo.gsd_m is None else photo.gsd_m
    lon_c, lat_c = grid.centre_lonlat()
    z = zoom_for_gsd(gsd, lat_c) if zoom is None else int(zoom)
    if not 0 <= z <= 30:
        raise InvalidInputError("zoom", f"must be in [0, 30], got {z}")
    tile_gsd = 2 * math.pi * 6378137.0 / TILE_PX * math.cos(math.radians(lat_c)) / 2**z
    ratio = tile_gsd / gsd
    rgb, scale = photo.rgb, 1.0
    valid = np.any(photo.rgb > 0, axis=2).astype(np.uint8)
    if ratio >= 1.15:
        w, h = photo.size
        sw, sh = max(2, round(w / ratio)), max(2, round(h / ratio))
        rgb = np.asarray(cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA), dtype=np.uint8)
        valid = np.asarray(cv2.resize(valid, (sw, sh), interpolation=cv2.INTER_NEAREST))
        scale = sw / w
    w, h = grid.size
    corners = grid.px_to_lonlat(
        [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]
    )
    world = lonlat_to_world_px(corners, z)
    x_lo, y_lo = (np.floor(world.min(axis=0)) // TILE_PX).astype(int)
    x_hi, y_hi = (np.floor(world.max(axis=0)) // TILE_PX).astype(int)
    keys = [(tx, ty) for ty in range(y_lo, y_hi + 1) for tx in range(x_lo, x_hi + 1)]
    stored = 0
    out_path = Path(out)
    with MBTilesWriter(out_path, overwrite=overwrite) as writer:
        for done, (tx, ty) in enumerate(keys, start=1):
            tile = render_tile(rgb, valid, grid, z, tx, ty, scale)
            if tile is not None:
                params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if tile_format == "jpg" else []
                ok, buf = cv2.imencode(f".{tile_format}", tile[:, :, ::-1], params)
                if not ok:
                    raise InvalidInputError("format", f"cannot encode tile {z}/{tx}/{ty}")
                writer.put_tile(z, tx, ty, buf.tobytes())
                stored += 1
            if progress is not None:
                progress(done, len(keys))
        lons, lats = corners[:, 0], corners[:, 1]
        writer.put_metadata(
            {
                "name": Path(geotiff).stem,
                "format": tile_format,
                "type": "baselayer",
                "version": "1.0",
                "description": f"web-mercator tiles of {Path(geotiff).name} (c3-matcher)",
                "attribution": attribution,
                "bounds": f"{lons.min():.7f},{lats.min():.7f},{lons.max():.7f},{lats.max():.7f}",
                "center": f"{lon_c:.7f},{lat_c:.7f},{z}",
                "minzoom": str(z),
                "maxzoom": str(z),
                "c3_source": Path(geotiff).name,
                "c3_source_epsg": str(grid.epsg),
                "c3_source_gsd_m": f"{gsd:.6f}",
                "c3_georeference": json.dumps(grid.projection.to_dict()),
            }
        )
    return BuildReport(
        out_path,
        z,
        stored,
        len(keys),
        tile_gsd,
        gsd,
        grid.projection.describe(),
        out_path.stat().st_size,
    )
