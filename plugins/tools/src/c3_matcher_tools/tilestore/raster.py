"""Read a GeoTIFF for ``tiles build`` through rasterio (the ``geo`` extra): windowed reads (one
window per tile, never the whole raster), the GeoTIFF nodata tag / internal mask / alpha band
(GDAL's dataset mask: where a file has both a nodata tag and an alpha band, the tag), and the
file's overviews for coarser zooms.

:func:`rasterio_available` says whether this path is used: rasterio importable and
``C3_MATCHER_TOOLS_NO_RASTERIO=1`` not set (that forces the hand-written tifffile fallback,
:func:`c3_matcher_tools.sim.orthophotos.load_orthophoto`, which reads the whole raster).

Pixels follow the fallback's rules so that both give the same tiles: bands 1-3 as RGB (NAIP's
4th band, NIR, is dropped), one band as grey; 16-bit / float data mapped linearly to 8 bits
(:class:`ValueMapping`, stated in the build report): by default 0 stays 0 and the 99.9th
percentile of the valid non-zero pixels becomes 255 (here estimated on a decimated read of at
most 1024 px a side); ``value_range="bits"`` maps the declared bit depth instead (the GDAL
``NBITS`` tag, e.g. 12-bit data in 16-bit words: 0..4095, else the integer type's range), and
``(lo, hi)`` maps lo..hi; a pixel is valid where GDAL's mask says so AND some band is
non-zero (the matcher's tile nodata convention is 0, :mod:`c3_matcher.preprocess`), and invalid
pixels are 0. For tiles coarser than the source by >= 1.15x the window is read at the tile's
resolution with GDAL ``average`` resampling (mask: nearest) from the finest overview not
coarser than the tile (the fallback area-downscales the whole image instead).
"""

from __future__ import annotations

import importlib.util
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.arrays import F64
from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import special_kind
from c3_matcher_tools.geodesy import ground_gsd_m
from c3_matcher_tools.geotiff import north_up_scale
from c3_matcher_tools.sim.orthophotos import expand_palette
from c3_matcher_tools.tilestore.geo import GeoGrid, check_grid_fits_crs
from c3_matcher_tools.tilestore.projection import Projection

__all__ = [
    "RasterioSource",
    "ValueMapping",
    "ValueRange",
    "check_pixel_type",
    "grid_gsd_m",
    "rasterio_available",
]

#: how source values become 8 bits: None (the 99.9th percentile), "bits" or (lo, hi)
ValueRange = str | tuple[float, float] | None


def rasterio_available() -> bool:
    """rasterio is importable and ``C3_MATCHER_TOOLS_NO_RASTERIO=1`` is not set."""
    if os.environ.get("C3_MATCHER_TOOLS_NO_RASTERIO") == "1":
        return False
    return importlib.util.find_spec("rasterio") is not None


def grid_gsd_m(grid: GeoGrid, *, geographic: bool) -> float:
    """Ground GSD (m/px) at the grid centre, the figure both ``tiles build`` readers report
    (:func:`~c3_matcher_tools.geodesy.ground_gsd_m`): projected units times the grid's metres per
    unit (``unit_m``: feet become metres) divided by the projection's scale factor at the centre
    (1.045 for PDC Mercator at 17 S, 0.984 for polar stereographic at 77.7 S, 0.9996 for UTM on
    its central meridian; 1 without pyproj but on mercator grids), degrees converted."""
    lon_deg, lat_deg = grid.centre_lonlat()
    return ground_gsd_m(
        grid.scale_x,
        grid.scale_y,
        lat_deg,
        geographic=geographic,
        epsg=grid.epsg,
        unit_m=grid.unit_m,
        lon_deg=lon_deg,
    )


def _linear_unit_m(crs: Any) -> float:
    """Metres per unit of a projected rasterio CRS's coordinates as GDAL reads them (0.3048 for
    feet); 1 for a geographic CRS (degrees: converted by the GSD rule) or one without a unit."""
    from rasterio.errors import CRSError

    if not crs.is_projected:
        return 1.0
    try:
        return float(crs.linear_units_factor[1])
    except CRSError:
        return 1.0


@dataclass(frozen=True)
class ValueMapping:
    """Source values ``lo``..``hi`` (of type ``dtype``) become 1..255 linearly (``v * 255 / hi``
    when ``lo`` is 0, so 0 stays nodata); ``how`` says where the range comes from."""

    dtype: str
    lo: float
    hi: float
    how: str

    def describe(self) -> str:
        if self.dtype == "uint8" and self.how == "as is":
            return "uint8 as is"
        if self.how == "colour map":
            return f"{self.dtype} palette indices -> RGB by the file's colour map"
        return f"{self.dtype} {self.lo:g}..{self.hi:g} -> 0..255 linear ({self.how})"

    def apply(self, data: NDArray[Any]) -> NDArray[np.uint8]:
        if self.how in ("as is", "colour map"):  # a palette's colours: expanded when read
            return np.asarray(data, dtype=np.uint8)
        scaled = (data.astype(np.float64) - self.lo) * (255.0 / max(self.hi - self.lo, 1e-12))
        scaled = np.nan_to_num(scaled, nan=0.0)  # a NaN nodata pixel: 0, as every invalid one
        return np.asarray(np.clip(np.rint(scaled), 0, 255), dtype=np.uint8)


def check_pixel_type(dtype: str, source: str | Path) -> str:
    """``dtype`` when its pixel values are real numbers (integers or floats); refused naming it
    otherwise (complex values, as a radar product's, have no brightness to map to 0..255; GDAL's
    complex integers, ``complex_int16``, have no numpy type at all)."""
    try:
        kind = np.dtype(dtype).kind
    except TypeError:
        kind = "c"
    if kind not in "uif":
        raise InvalidInputError(
            "geotiff",
            f"{source}: its pixels are {dtype}, not integers or real numbers: an orthophoto's "
            "are (convert it to 8- or 16-bit, or float, first)",
        )
    return dtype


def declared_range(dtype: str, nbits: str | None, source: str | Path) -> tuple[float, str]:
    """(top value, how) of the declared bit depth: ``NBITS`` when declared, else the integer
    type's maximum; float data declares none."""
    if nbits:
        return float(2 ** int(nbits) - 1), f"declared bit depth NBITS={int(nbits)}"
    if np.dtype(dtype).kind in "ui":
        bits = np.iinfo(np.dtype(dtype)).bits
        return float(np.iinfo(np.dtype(dtype)).max), f"the {bits}-bit type's range"
    raise InvalidInputError(
        "--value-range", f"{source}: {dtype} data has no bit depth: give LO,HI or leave it auto"
    )


def colour_table(ds: Any, source: str | Path) -> NDArray[np.uint8] | None:
    """The RGB colour of each palette index (index -> row) of a one-band palette raster, as
    GDAL reads its colour map (an entry with alpha 0 is black: nodata); None for any other.
    Palettes are expanded rather than refused: a scanned map or a colour-reduced orthophoto is
    still an image to match, and its indices read as grey would be noise."""
    from rasterio.enums import ColorInterp

    if ds.count < 1 or ds.colorinterp[0] != ColorInterp.palette:
        return None
    try:
        cmap = ds.colormap(1)
    except ValueError as exc:
        raise InvalidInputError(
            "geotiff", f"{source}: a palette image without a colour map"
        ) from exc
    kind = np.dtype(str(ds.dtypes[0]))
    if kind.kind != "u" or kind.itemsize > 2:
        raise InvalidInputError("geotiff", f"{source}: a palette of {kind} indices: not 8/16-bit")
    table = np.zeros((np.iinfo(kind).max + 1, 3), dtype=np.uint8)
    for index, (r, g, b, *alpha) in cmap.items():
        if 0 <= index < len(table) and (not alpha or alpha[0] > 0):
            table[index] = (r, g, b)
    return table


def _gdal_why(exc: BaseException) -> str:
    """GDAL's own words for a failed read: the innermost cause of rasterio's exception (whose
    message only says "see previous exception"), on one line."""
    while exc.__cause__ is not None:
        exc = exc.__cause__
    return " ".join(str(exc).split())


class RasterioSource:
    """An open GeoTIFF: ``grid``, ``gsd_m``, ``nodata`` (the tag, or None), ``overviews``
    (decimation factors) and :meth:`sample` (one tile's pixels through a windowed read)."""

    def __init__(
        self,
        path: str | Path,
        *,
        reference: tuple[float, float] | None = None,
        value_range: ValueRange = None,
    ) -> None:
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning

        self.path = Path(path)
        kind = special_kind(self.path)
        if kind is not None:  # a FIFO would be waited on forever
            raise InvalidInputError("geotiff", f"{self.path}: is {kind}, not a GeoTIFF")
        if not self.path.is_file():
            raise InvalidInputError("geotiff", f"no such file: {self.path}")
        try:
            with warnings.catch_warnings():  # a plain image: said below in one line
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                ds = rasterio.open(self.path)
        except Exception as exc:  # RasterioIOError and friends
            raise InvalidInputError(
                "geotiff", f"{self.path}: not a readable raster: {' '.join(str(exc).split())}"
            ) from exc
        self._levels: dict[int, Any] = {-1: ds}
        try:
            self._describe(ds, reference, value_range)
        except BaseException:
            ds.close()
            raise
        self.levels_used: set[int] = set()

    def _describe(
        self, ds: Any, reference: tuple[float, float] | None, value_range: ValueRange
    ) -> None:
        """The open dataset's grid, GSD, bands, nodata, overviews and value mapping; refuses a
        raster without a north-up georeference or whose coordinates do not fit its CRS."""
        t = ds.transform
        if ds.crs is None:
            raise InvalidInputError(
                "geotiff",
                f"{self.path}: no georeference (no CRS{' or pixel grid' if t.is_identity else ''}"
                "): tiles build needs a GeoTIFF",
            )
        matrix = (float(t.a), float(t.b), float(t.c), float(t.d), float(t.e), float(t.f))
        sx, sy = north_up_scale(matrix, self.path)
        epsg = ds.crs.to_epsg()
        w, h = int(ds.width), int(ds.height)
        origin_e, origin_n = float(t.c), float(t.f)
        projection = Projection.from_epsg(
            None if epsg is None else int(epsg),
            reference=reference,
            ref_en=(origin_e + w / 2 * sx, origin_n - h / 2 * sy),
            source=self.path,
        )
        unit_m = _linear_unit_m(ds.crs)
        self.grid = GeoGrid(origin_e, origin_n, sx, sy, (w, h), epsg, projection, unit_m)
        check_grid_fits_crs(self.grid, self.path)
        self.gsd_m = grid_gsd_m(self.grid, geographic=bool(ds.crs.is_geographic))
        self.palette = colour_table(ds, self.path)
        self.bands = [1] if self.palette is not None else [1, 2, 3] if ds.count >= 3 else [1]
        self.nodata = ds.nodata
        self.overviews: list[int] = list(ds.overviews(1))
        self.mapping = self._mapping(ds, value_range)

    def _mapping(self, ds: Any, value_range: ValueRange) -> ValueMapping:
        dtype = check_pixel_type(str(ds.dtypes[0]), self.path)
        if self.palette is not None:
            if value_range not in (None, "auto"):
                raise InvalidInputError(
                    "--value-range",
                    f"{self.path}: a palette image: its colours come from its colour map, "
                    "there is no value range to give",
                )
            return ValueMapping(dtype, 0.0, 255.0, "colour map")
        if isinstance(value_range, tuple):
            lo, hi = (float(v) for v in value_range)
            if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
                raise InvalidInputError("--value-range", f"expected LO < HI, got {lo},{hi}")
            return ValueMapping(dtype, lo, hi, "given")
        if value_range == "bits":
            top, how = declared_range(
                dtype, ds.tags(1, ns="IMAGE_STRUCTURE").get("NBITS"), self.path
            )
            return ValueMapping(dtype, 0.0, top, how)
        if value_range not in (None, "auto"):
            raise InvalidInputError(
                "--value-range", f"expected auto, bits or LO,HI, got {value_range!r}"
            )
        if dtype == "uint8":
            return ValueMapping(dtype, 0.0, 255.0, "as is")
        w, h = self.grid.size
        f = max(1, math.ceil(max(w, h) / 1024))
        data, mask = self._read(ds, None, (max(1, h // f), max(1, w // f)), average=True)
        good = data[:, mask > 0]
        nonzero = good[good > 0]
        top = float(np.percentile(nonzero, 99.9)) if nonzero.size else 1.0
        return ValueMapping(dtype, 0.0, top, "99.9th percentile of the valid pixels")

    def close(self) -> None:
        for ds in self._levels.values():
            ds.close()
        self._levels.clear()

    def __enter__(self) -> RasterioSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _level(self, ratio: float) -> tuple[Any, int]:
        """(dataset, overview index or -1) of the finest overview not coarser than ``ratio``."""
        import rasterio

        index = -1
        for i, f in enumerate(self.overviews):
            if f <= ratio:
                index = i
        if index not in self._levels:
            self._levels[index] = rasterio.open(self.path, overview_level=index)
        return self._levels[index], index

    def _read(
        self, ds: Any, window: Any, out_shape: tuple[int, int] | None, *, average: bool
    ) -> tuple[NDArray[Any], NDArray[np.uint8]]:
        from rasterio.enums import Resampling
        from rasterio.errors import NodataShadowWarning, RasterioError

        shape = None  # a palette's indices: read whole, averaged once expanded
        if out_shape is not None and self.palette is None:
            shape = (len(self.bands), *out_shape)
        try:
            data = ds.read(
                self.bands,
                window=window,
                out_shape=shape,
                resampling=Resampling.average if average else Resampling.nearest,
            )
            if self.palette is not None:  # indices at full resolution, averaged as colours
                data = expand_palette(data[0], self.palette, out_shape)
            with warnings.catch_warnings():  # a nodata tag beside an alpha band: GDAL's
                warnings.simplefilter("ignore", NodataShadowWarning)  # mask follows the tag
                mask = ds.dataset_mask(
                    window=window, out_shape=out_shape, resampling=Resampling.nearest
                )
        except RasterioError as exc:
            raise InvalidInputError(
                "geotiff",
                f"{self.path}: damaged raster, its pixels cannot be read ({_gdal_why(exc)})",
            ) from exc
        return data, np.asarray(mask, dtype=np.uint8)

    def sample(
        self, uv: F64, ratio: float
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8], F64, F64] | None:
        """For sample points ``uv`` (N, 2) ORTHO px of the full-resolution grid and a tile
        coarser than the source by ``ratio``: (rgb window uint8 (h, w, 3), valid (h, w) 0/1,
        map_x, map_y (N,) in window px), or None when the points miss the raster."""
        from rasterio.windows import Window

        ds, index = self._level(ratio)
        w, h = self.grid.size
        fx, fy = ds.width / w, ds.height / h
        lu = (uv[:, 0] + 0.5) * fx - 0.5
        lv = (uv[:, 1] + 0.5) * fy - 0.5
        eff = ratio * min(fx, fy)
        pad = 2 + math.ceil(max(eff, 1.0))
        c0 = max(0, math.floor(float(lu.min())) - pad)
        r0 = max(0, math.floor(float(lv.min())) - pad)
        c1 = min(ds.width, math.ceil(float(lu.max())) + pad + 1)
        r1 = min(ds.height, math.ceil(float(lv.max())) + pad + 1)
        if c1 <= c0 or r1 <= r0:
            return None
        self.levels_used.add(index)
        window = Window(c0, r0, c1 - c0, r1 - r0)
        cw, rh = c1 - c0, r1 - r0
        if eff >= 1.15:
            ow, oh = max(2, round(cw / eff)), max(2, round(rh / eff))
            data, mask = self._read(ds, window, (oh, ow), average=True)
            kx, ky = ow / cw, oh / rh
        else:
            data, mask = self._read(ds, window, None, average=False)
            kx = ky = 1.0
        rgb = np.ascontiguousarray(np.moveaxis(self.mapping.apply(data), 0, -1))
        if rgb.shape[2] == 1:
            rgb = np.repeat(rgb, 3, axis=2)
        valid = ((mask > 0) & np.any(rgb > 0, axis=2)).astype(np.uint8)
        rgb[valid == 0] = 0
        map_x = (lu - c0 + 0.5) * kx - 0.5
        map_y = (lv - r0 + 0.5) * ky - 0.5
        return rgb, valid, map_x, map_y
