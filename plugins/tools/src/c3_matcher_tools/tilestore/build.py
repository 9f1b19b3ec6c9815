"""Build an MBTiles store of 256-px web-mercator tiles from a north-up GeoTIFF orthophoto.

Every tile pixel centre (WORLD px) is converted to (lon, lat), then to the GeoTIFF's projected
metres and ORTHO px (:mod:`c3_matcher.tilestore.geo`: exact for UTM / mercator / geographic
grids, a documented local tangent plane otherwise), and sampled bilinearly
(``cv2.remap``; the orthophoto is first area-downscaled when the tiles are >= 1.15x coarser).
Pixels outside the orthophoto or on its nodata (all bands 0; with rasterio also the GeoTIFF nodata
tag, internal mask or alpha band) are 0 (nodata); tiles with no data are not stored. With
rasterio (the ``geo`` extra; :mod:`c3_matcher_tools.tilestore.raster`) each tile is read through
its own window (never the whole raster) and coarser zooms read the file's overviews; without it
(or with ``C3_MATCHER_TOOLS_NO_RASTERIO=1``) the whole raster is loaded with tifffile. Several
zooms can be written into one store. The zoom defaults to the coarsest whose ground GSD at the
image centre is at most the orthophoto's (:func:`c3_matcher_tools.tilestore.geo.zoom_for_gsd`).

The tiles planned are those along the orthophoto's outline (its edges sampled, not only its
corners), their columns modulo 2**zoom across 180 deg, their rows within the web-mercator world
(the share of the orthophoto beyond +-85.0511 deg is reported as ``beyond_world_pct``).

Refused before any tile is written (``InvalidInputError``): coordinates that do not fit the CRS
(:func:`~c3_matcher_tools.tilestore.geo.check_grid_fits_crs`), a grid holding a pole or wholly
beyond the web-mercator world (:func:`~c3_matcher_tools.tilestore.geo.refuse_off_the_tiles`),
an implausible ground GSD, and, unless ``force``, a zoom whose tiles are more than
:data:`MAX_UPSAMPLE` times finer than the source (invented detail, and 4x the tiles per zoom
step). A build that stores no tile is refused too. The store is written atomically
(:class:`MBTilesWriter`). Non-8-bit data is mapped to 8 bits as the report's ``value_mapping``
says (:class:`~c3_matcher_tools.tilestore.raster.ValueMapping`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import MERCATOR_MAX_LAT
from c3_matcher_tools.geotiff import MODEL_TYPE_KEY, geo_keys, grid_tags
from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.tilestore.geo import (
    TILE_PX,
    GeoGrid,
    check_source_gsd,
    grid_outline_lonlat,
    read_geotiff_grid,
    refuse_off_the_tiles,
    share_beyond_world,
    tile_ranges,
    world_px_to_lonlat,
    zoom_for_gsd,
)
from c3_matcher_tools.tilestore.projection import wrap_lon
from c3_matcher_tools.tilestore.raster import (
    RasterioSource,
    ValueMapping,
    ValueRange,
    check_pixel_type,
    grid_gsd_m,
    rasterio_available,
)
from c3_matcher_tools.tilestore.writer import MBTilesWriter

__all__ = ["MAX_UPSAMPLE", "BuildReport", "build_mbtiles", "parse_zooms", "render_tile"]

Progress = Callable[[int, int], None]
#: the tifffile fallback's raster for one zoom: RGB, valid mask, (x, y) scale from the source's
#: pixels (each axis its own: the rounded sizes differ in ratio)
_Scaled = tuple[NDArray[np.uint8], NDArray[np.uint8], tuple[float, float]]

#: the finest tiles built without ``force``: this many times finer than the source's GSD
MAX_UPSAMPLE = 4.0


@dataclass(frozen=True)
class BuildReport:
    """What ``build_mbtiles`` wrote: ``tiles`` stored (of ``candidates`` in the bounds) over
    ``zooms`` (``zoom`` the finest, ``tile_gsd_m`` its GSD; ``tiles_per_zoom``), read with
    ``reader`` (``rasterio`` or ``tifffile``); ``value_mapping`` says how the source's values
    became 8 bits; ``beyond_world_pct`` how much of the orthophoto (% of its pixels) lies beyond
    the web-mercator world (|lat| > 85.0511 deg) and is in no tile."""

    path: Path
    zoom: int
    tiles: int
    candidates: int
    tile_gsd_m: float
    source_gsd_m: float
    georeference: str
    bytes: int
    zooms: tuple[int, ...] = ()
    tiles_per_zoom: dict[str, int] | None = None
    reader: str = "tifffile"
    nodata: float | None = None
    overview_levels: tuple[int, ...] = ()
    value_mapping: str = "uint8 as is"
    beyond_world_pct: float = 0.0


def _tile_uv(grid: GeoGrid, zoom: int, x: int, y: int) -> NDArray[np.float64]:
    """ORTHO px (N, 2) of the centres of tile (zoom, x, y)'s pixels, row-major."""
    i = np.arange(TILE_PX, dtype=np.float64) + 0.5
    wx, wy = np.meshgrid(x * TILE_PX + i, y * TILE_PX + i)
    lonlat = world_px_to_lonlat(np.stack([wx.ravel(), wy.ravel()], axis=1), zoom)
    return grid.lonlat_to_px(lonlat)


def _remap(
    ortho: NDArray[np.uint8],
    valid: NDArray[np.uint8],
    map_x: NDArray[np.float64],
    map_y: NDArray[np.float64],
) -> NDArray[np.uint8] | None:
    mx = map_x.reshape(TILE_PX, TILE_PX).astype(np.float32)
    my = map_y.reshape(TILE_PX, TILE_PX).astype(np.float32)
    mask = cv2.remap(valid, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    if not mask.any():
        return None
    img = cv2.remap(ortho, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    img[mask == 0] = 0
    return np.asarray(img, dtype=np.uint8)


def render_tile(
    ortho: NDArray[np.uint8],
    valid: NDArray[np.uint8],
    grid: GeoGrid,
    zoom: int,
    x: int,
    y: int,
    scale: float | tuple[float, float] = 1.0,
) -> NDArray[np.uint8] | None:
    """Tile (zoom, x, y) resampled from ``ortho`` (uint8 RGB, possibly pre-scaled by ``scale``
    relative to ``grid``'s pixels: one factor, or (x, y) when the axes were scaled apart) with
    nodata 0, or None when it holds no data."""
    kx, ky = (scale, scale) if isinstance(scale, (int, float)) else scale
    uv = _tile_uv(grid, zoom, x, y)
    return _remap(ortho, valid, (uv[:, 0] + 0.5) * kx - 0.5, (uv[:, 1] + 0.5) * ky - 0.5)


def parse_zooms(values: Sequence[int | str] | None) -> list[int] | None:
    """Zoom list from ints and ``"A-B"`` ranges (sorted, unique), or None for the default."""
    if not values:
        return None
    out: set[int] = set()
    for v in values:
        text = str(v).strip()
        try:
            if "-" in text[1:]:
                lo, hi = (int(t) for t in text.split("-"))
                out.update(range(min(lo, hi), max(lo, hi) + 1))
            else:
                out.add(int(text))
        except ValueError:
            raise InvalidInputError("--zooms", f"expected Z or A-B, got {text!r}") from None
    for z in out:
        if not 0 <= z <= 30:
            raise InvalidInputError("zoom", f"must be in [0, 30], got {z}")
    return sorted(out)


@dataclass(frozen=True)
class _Source:
    """The orthophoto as a build reads it: its grid and GSD, what the report says of it
    (``reader``, ``nodata``, ``mapping``), and its pixels: ``raster`` (rasterio, one window per
    tile) or ``photo_rgb`` (tifffile, the whole raster)."""

    grid: GeoGrid
    gsd: float
    reader: str
    nodata: float | None
    mapping: str
    raster: RasterioSource | None = None
    photo_rgb: NDArray[np.uint8] | None = None

    def close(self) -> None:
        """Close the rasterio dataset (the tifffile raster is already in memory)."""
        if self.raster is not None:
            self.raster.close()


@dataclass(frozen=True)
class _Output:
    """Where and how the tiles are written: the store, its tile encoding and its metadata's
    attribution; ``overwrite`` replaces an existing store."""

    path: Path
    tile_format: str
    jpeg_quality: int
    attribution: str
    overwrite: bool


@dataclass(frozen=True)
class _Plan:
    """The tiles a build covers: per zoom (``zooms``, ascending) the tile columns and rows
    (``ranges``; columns unwrapped across 180 deg, meant modulo 2**zoom) around the orthophoto's
    ``corners`` (lon, lat, unwrapped around the centre's); ``centre`` (lon, lat) is the image
    centre, ``default_zoom`` the source's own zoom and ``beyond_world`` the share of the
    orthophoto beyond the web-mercator world."""

    zooms: tuple[int, ...]
    default_zoom: int
    centre: tuple[float, float]
    corners: NDArray[np.float64]
    ranges: dict[int, tuple[range, range]]
    beyond_world: float = 0.0

    @property
    def planned(self) -> int:
        """How many tiles the bounds hold over every zoom."""
        return sum(len(xs) * len(ys) for xs, ys in self.ranges.values())

    def jobs(self) -> list[tuple[int, int, int]]:
        """(zoom, x, y) of every tile in the bounds: zoom by zoom, row by row, west to east
        (across 180 deg from the world's last columns to its first)."""
        return [
            (z, tx % (1 << z), ty) for z, (xs, ys) in self.ranges.items() for ty in ys for tx in xs
        ]

    def tile_gsd(self, z: int) -> float:
        """The ground GSD (m/px) of zoom ``z``'s tiles at the image centre."""
        return TileId(z, self.centre[1], self.centre[0]).web_mercator_gsd_m()


def build_mbtiles(
    geotiff: str | Path,
    out: str | Path,
    *,
    zoom: int | Sequence[int] | None = None,
    tile_format: str = "png",
    jpeg_quality: int = 90,
    reference: tuple[float, float] | None = None,
    attribution: str = "",
    overwrite: bool = False,
    progress: Progress | None = None,
    use_rasterio: bool | None = None,
    value_range: ValueRange = None,
    force: bool = False,
) -> BuildReport:
    """Write ``out`` (MBTiles) from ``geotiff`` at ``zoom`` (one zoom, several, or None: the
    default of :func:`zoom_for_gsd`); ``reference`` (lat, lon) of the image centre is needed
    for grids that are not UTM / mercator / geographic without pyproj (local tangent plane).
    With rasterio (``use_rasterio`` None: :func:`rasterio_available`) the GeoTIFF is read one
    window per tile, its nodata tag honoured and its overviews used; otherwise the whole
    raster is loaded with tifffile. ``progress`` is called with (done, total) after every
    tile. ``value_range`` (rasterio only): None / ``"auto"`` (99.9th percentile), ``"bits"``
    (declared bit depth) or (lo, hi), for non-8-bit data. ``force`` builds a zoom more than
    :data:`MAX_UPSAMPLE` times finer than the source. ``out`` is never ``geotiff`` itself
    (refused, ``overwrite`` or not)."""
    from c3_matcher.atomic import refuse_output_over_inputs

    refuse_output_over_inputs(Path(out), [geotiff])
    if tile_format not in ("png", "jpg"):
        raise InvalidInputError("format", f"expected png or jpg, got {tile_format!r}")
    if isinstance(zoom, (int, np.integer)):
        zooms = parse_zooms([int(zoom)])
    else:
        zooms = parse_zooms(list(zoom) if zoom is not None else None)
    if use_rasterio is None:
        use_rasterio = rasterio_available()
    source = _open_source(geotiff, reference, use_rasterio, value_range)
    output = _Output(Path(out), tile_format, jpeg_quality, attribution, overwrite)
    try:
        check_source_gsd(source.gsd, geotiff)
        return _build(geotiff, source, zooms, output, progress, force)
    finally:
        source.close()


def _open_source(
    geotiff: str | Path,
    reference: tuple[float, float] | None,
    use_rasterio: bool,
    value_range: ValueRange,
) -> _Source:
    """``geotiff`` opened with rasterio (read a window at a time), or loaded whole with
    tifffile: then a ``value_range`` other than the default is refused (rasterio's alone), and
    so are pixels that do not match the grid."""
    if use_rasterio:
        raster = RasterioSource(geotiff, reference=reference, value_range=value_range)
        return _Source(
            raster.grid, raster.gsd_m, "rasterio", raster.nodata, raster.mapping.describe(), raster
        )
    if value_range not in (None, "auto"):
        raise InvalidInputError("--value-range", "needs the rasterio reader (the geo extra)")
    grid = read_geotiff_grid(geotiff, reference=reference)
    mapping = _fallback_mapping(geotiff)  # before the pixels: it refuses complex ones
    photo = load_orthophoto(geotiff)
    if photo.size != grid.size:
        raise InvalidInputError(
            "geotiff", f"{geotiff}: pixel size {photo.size} != grid {grid.size}"
        )
    gsd = grid_gsd_m(grid, geographic=_declared_geographic(geotiff))
    return _Source(grid, gsd, "tifffile", None, mapping, photo_rgb=photo.rgb)


def _declared_geographic(geotiff: str | Path) -> bool:
    """Whether ``geotiff``'s GeoKeys declare a geographic model (degrees), as the tifffile
    reader's GSD rule reads them (:func:`~c3_matcher_tools.sim.orthophotos.geotiff_gsd_m`)."""
    import tifffile

    with tifffile.TiffFile(str(geotiff)) as tif:
        keys = geo_keys(grid_tags(tif.pages.first), geotiff)
    return bool(keys.get(MODEL_TYPE_KEY) == 2)


def _fallback_mapping(geotiff: str | Path) -> str:
    """The tifffile fallback's mapping (``load_orthophoto``: the whole raster's percentile)."""
    import tifffile

    with tifffile.TiffFile(str(geotiff)) as tif:
        dtype = check_pixel_type(str(tif.pages.first.dtype), geotiff)
    if dtype == "uint8":
        return ValueMapping(dtype, 0.0, 255.0, "as is").describe()
    return f"{dtype} 0..p99.9 -> 0..255 linear (99.9th percentile of the non-zero pixels)"


def _build(
    geotiff: str | Path,
    source: _Source,
    zooms: list[int] | None,
    output: _Output,
    progress: Progress | None,
    force: bool,
) -> BuildReport:
    """Plan the tiles, refuse a zoom of invented detail (unless ``force``), write every tile
    that holds data and the store's metadata, and report; a store with no tile is refused."""
    plan = _plan(geotiff, source, zooms)
    _refuse_too_fine(plan, source.gsd, force)
    jobs = plan.jobs()
    with MBTilesWriter(output.path, overwrite=output.overwrite) as writer:
        per_zoom = _write_tiles(writer, source, plan, jobs, output, progress)
        if not any(per_zoom.values()):
            raise InvalidInputError(
                "geotiff",
                f"{geotiff}: no tile holds data at zoom {'/'.join(map(str, plan.zooms))} "
                f"({len(jobs)} in the bounds): the raster is all nodata (0); nothing written",
            )
        writer.put_metadata(_metadata(geotiff, source, plan, output))
    finest = max(plan.zooms)
    return BuildReport(
        output.path,
        finest,
        sum(per_zoom.values()),
        len(jobs),
        plan.tile_gsd(finest),
        source.gsd,
        source.grid.projection.describe(),
        output.path.stat().st_size,
        plan.zooms,
        per_zoom,
        source.reader,
        None if source.nodata is None else float(source.nodata),
        tuple(sorted(source.raster.levels_used)) if source.raster is not None else (),
        source.mapping,
        round(plan.beyond_world * 100.0, 2),
    )


def _plan(geotiff: str | Path, source: _Source, zooms: list[int] | None) -> _Plan:
    """The tiles covering the orthophoto at ``zooms`` (None: the source's own zoom): along its
    outline, across 180 deg where it crosses it, within the web-mercator world (a grid that
    holds a pole or lies wholly beyond the world is refused, naming ``geotiff``)."""
    grid = source.grid
    centre = grid.centre_lonlat()
    default_zoom = zoom_for_gsd(source.gsd, centre[1])
    if zooms is None:
        zooms = [default_zoom]
    outline = grid_outline_lonlat(grid)
    refuse_off_the_tiles(grid, outline, geotiff)
    w, h = grid.size
    corners = grid.px_to_lonlat(
        [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]
    )
    corners[:, 0] = wrap_lon(corners[:, 0], centre[0])
    ranges = {z: tile_ranges(outline, z) for z in zooms}
    beyond = share_beyond_world(grid, outline)
    return _Plan(tuple(zooms), default_zoom, centre, corners, ranges, beyond)


def _refuse_too_fine(plan: _Plan, gsd: float, force: bool) -> None:
    """Unless ``force``, refuse a zoom more than :data:`MAX_UPSAMPLE` times finer than the
    source's ``gsd`` (naming the finest such zoom)."""
    too_fine = [z for z in plan.zooms if plan.tile_gsd(z) * MAX_UPSAMPLE < gsd]
    if too_fine and not force:
        z = max(too_fine)
        tile_gsd = plan.tile_gsd(z)
        raise InvalidInputError(
            "--zoom",
            f"zoom {z} ({tile_gsd:.3g} m/px) is {gsd / tile_gsd:,.0f}x finer than the "
            f"source ({gsd:.3g} m/px): {plan.planned:,} tiles planned, of invented detail; the "
            f"source's zoom is {plan.default_zoom} (the default). Use --force to build it anyway",
        )


def _write_tiles(
    writer: MBTilesWriter,
    source: _Source,
    plan: _Plan,
    jobs: Sequence[tuple[int, int, int]],
    output: _Output,
    progress: Progress | None,
) -> dict[str, int]:
    """Render, encode and store each of ``jobs`` that holds data, calling ``progress`` after
    every tile; the tiles stored per zoom (``"z"``)."""
    per_zoom = {str(z): 0 for z in plan.zooms}
    scaled: dict[int, _Scaled] = {}
    for done, (z, tx, ty) in enumerate(jobs, start=1):
        tile = _render(source, z, tx, ty, plan.tile_gsd(z) / source.gsd, scaled)
        if tile is not None:
            writer.put_tile(z, tx, ty, _encode(tile, output, z, tx, ty))
            per_zoom[str(z)] += 1
        if progress is not None:
            progress(done, len(jobs))
    return per_zoom


def _render(
    source: _Source, z: int, x: int, y: int, ratio: float, scaled: dict[int, _Scaled]
) -> NDArray[np.uint8] | None:
    """Tile (z, x, y), ``ratio`` times coarser than the source, or None when it holds no
    data: read through its own window (rasterio), or resampled from the whole raster,
    area-downscaled once per zoom into ``scaled`` (tifffile)."""
    if source.raster is not None:
        got = source.raster.sample(_tile_uv(source.grid, z, x, y), ratio)
        return None if got is None else _remap(*got)
    assert source.photo_rgb is not None
    if z not in scaled:
        scaled[z] = _downscaled(source.photo_rgb, ratio)
    rgb, valid, scale = scaled[z]
    return render_tile(rgb, valid, source.grid, z, x, y, scale)


def _encode(tile: NDArray[np.uint8], output: _Output, z: int, x: int, y: int) -> bytes:
    """Tile (z, x, y) (RGB) encoded as the store's PNG or JPEG."""
    params = [cv2.IMWRITE_JPEG_QUALITY, output.jpeg_quality] if output.tile_format == "jpg" else []
    ok, buf = cv2.imencode(f".{output.tile_format}", tile[:, :, ::-1], params)
    if not ok:
        raise InvalidInputError("format", f"cannot encode tile {z}/{x}/{y}")
    return buf.tobytes()


def _metadata(geotiff: str | Path, source: _Source, plan: _Plan, output: _Output) -> dict[str, str]:
    """The store's MBTiles metadata, with the source's georeference, reader and mapping; its
    bounds within the web-mercator world (west > east across 180 deg)."""
    lons = wrap_lon([plan.corners[:, 0].min(), plan.corners[:, 0].max()])
    lats = np.clip(plan.corners[:, 1], -MERCATOR_MAX_LAT, MERCATOR_MAX_LAT)
    lon_c, lat_c = (
        plan.centre[0],
        float(np.clip(plan.centre[1], -MERCATOR_MAX_LAT, MERCATOR_MAX_LAT)),
    )
    grid, nodata = source.grid, source.nodata
    return {
        "name": Path(geotiff).stem,
        "format": output.tile_format,
        "type": "baselayer",
        "version": "1.0",
        "description": f"web-mercator tiles of {Path(geotiff).name} (c3-matcher)",
        "attribution": output.attribution,
        "bounds": f"{lons[0]:.7f},{lats.min():.7f},{lons[1]:.7f},{lats.max():.7f}",
        "center": f"{lon_c:.7f},{lat_c:.7f},{max(plan.zooms)}",
        "minzoom": str(min(plan.zooms)),
        "maxzoom": str(max(plan.zooms)),
        "c3_source": Path(geotiff).name,
        "c3_source_epsg": str(grid.epsg),
        "c3_source_gsd_m": f"{source.gsd:.6f}",
        "c3_georeference": json.dumps(grid.projection.to_dict()),
        "c3_reader": source.reader,
        "c3_source_value_mapping": source.mapping,
        **({} if nodata is None else {"c3_source_nodata": repr(float(nodata))}),
    }


def _downscaled(rgb: NDArray[np.uint8], ratio: float) -> _Scaled:
    """The fallback's whole-image area downscale for tiles >= 1.15x coarser than the source,
    with its scale on each axis (the sizes are rounded apart: 0.5 px over the height is half a
    tile pixel misplaced at the bottom if the width's scale stood for both)."""
    valid = np.any(rgb > 0, axis=2).astype(np.uint8)
    if ratio < 1.15:
        return rgb, valid, (1.0, 1.0)
    h, w = rgb.shape[:2]
    sw, sh = max(2, round(w / ratio)), max(2, round(h / ratio))
    small = np.asarray(cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA), dtype=np.uint8)
    small_valid = np.asarray(cv2.resize(valid, (sw, sh), interpolation=cv2.INTER_NEAREST))
    return small, small_valid, (sw / w, sh / h)
