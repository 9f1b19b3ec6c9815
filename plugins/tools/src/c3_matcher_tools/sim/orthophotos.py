"""Load a north-up orthophoto as uint8 RGB plus its ground sample distance (m/px).

Pixels: TIFFs are read with ``tifffile`` when it is importable and can decode them (raw bands;
JPEG-compressed TIFFs need the optional ``imagecodecs``), otherwise, and for every other
format, with ``cv2.imread(IMREAD_UNCHANGED)``. Bands: grey -> RGB; 3 bands -> RGB;
4 bands -> the first three as RGB (NAIP's R, G, B, NIR; an RGBA PNG's alpha == 0 becomes nodata
0). 16-bit or float data is stretched linearly to 8 bits (0 stays 0, the 99.9th percentile of
the non-zero pixels becomes 255). A palette TIFF (one band of indices and a colour map) is
expanded to the map's RGB colours, as GDAL reads it (:func:`expand_palette`): its indices are
no brightness.

Caveat: OpenCV's TIFF reader (libtiff RGBA interface) PREMULTIPLIES the colour bands by the
fourth band when it is tagged as unassociated alpha, which NAIP's NIR band is; a 4-band TIFF is
therefore refused without ``tifffile`` rather than silently corrupted.

GSD: from the GeoTIFF tags (ModelPixelScaleTag 33550, ModelTiepointTag 33922,
GeoKeyDirectoryTag 34735) when ``tifffile`` is importable. Projected CRSs in metres (UTM, RD New,
LV95, ...) give the pixel scale directly (their scale error, < 0.1 %, is ignored); those in feet
(US state planes) are converted by the declared ProjLinearUnitsGeoKey or, without it, by the
EPSG code's unit (pyproj). Mercator pixel scales are not ground metres: EPSG:3395 (ellipsoidal
World Mercator) and EPSG:3857 (web mercator) are corrected at the image centre's latitude, read
from the tie point. Geographic
CRSs (degrees) are converted at the centre's latitude. Without ``tifffile`` or tags, the
:data:`KNOWN_GSD_M` table of the fixtures (data/imagery/ATTRIBUTION.md) is used, by file name.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.geodesy import (
    MERCATOR_EPSG,
    ground_gsd_m,
    mercator_latitude_deg,
    projected_unit,
)
from c3_matcher_tools.geotiff import (
    MODEL_TYPE_KEY,
    PROJ_LINEAR_UNITS_KEY,
    PROJECTED_CRS_KEY,
    geo_keys,
    grid_tags,
    pixel_scale,
    tiepoint,
)

__all__ = ["KNOWN_GSD_M", "Orthophoto", "expand_palette", "geotiff_gsd_m", "load_orthophoto"]

#: Fallback GSDs (m/px) of the fixture orthophotos, from data/imagery/ATTRIBUTION.md. The two
#: OpenAerialMap images are EPSG:3395 with a ~0.10 m pixel scale; their ground GSD is ~0.097 m
#: (Manila, 14.6 N) and ~0.096 m (Brazil, 15.6 S), which the GeoTIFF path computes exactly.
KNOWN_GSD_M: dict[str, float] = {
    "m_4709963_se_14_1_20100629.tif": 5.0,
    "m_4709963_se_14_1_20150926.tif": 5.0,
    "m_4709963_se_14_1_20200831.tif": 5.0,
    "test_tiled.tif": 0.25,
    "5b90f92da0d7280005fab355_4310.tif": 0.10,
    "5dded5bc0140b80006d2e565_23.tif": 0.10,
    "swissimage_zurich_1091-322_00_0p5m.tif": 0.5,
    "swissimage_ref-img_0p5m.tif": 0.5,
}


@dataclass(frozen=True)
class Orthophoto:
    """A north-up orthophoto: ``rgb`` uint8 (H, W, 3) (nodata = all channels 0), ``gsd_m``
    ground metres per pixel (None when unknown), ``gsd_source`` one of "geotiff", "table",
    "given", "unknown"."""

    rgb: NDArray[np.uint8]
    gsd_m: float | None
    path: Path
    gsd_source: str

    @property
    def size(self) -> tuple[int, int]:
        """(w, h) px."""
        return int(self.rgb.shape[1]), int(self.rgb.shape[0])


def _to_uint8(arr: NDArray[Any]) -> NDArray[np.uint8]:
    if arr.dtype == np.uint8:
        return arr
    data = arr.astype(np.float64)
    nonzero = data[data > 0]
    top = float(np.percentile(nonzero, 99.9)) if nonzero.size else 1.0
    return np.asarray(np.clip(np.rint(data * (255.0 / max(top, 1e-12))), 0, 255), dtype=np.uint8)


def expand_palette(
    indices: NDArray[Any], table: NDArray[np.uint8], out_shape: tuple[int, int] | None = None
) -> NDArray[np.uint8]:
    """Palette ``indices`` (H, W) as RGB bands (3, H, W) by ``table`` (index -> RGB row),
    area-averaged to ``out_shape`` (h, w) when given: colours average, indices do not."""
    rgb = table[np.asarray(indices)]
    if out_shape is not None and out_shape != rgb.shape[:2]:
        rgb = cv2.resize(rgb, (out_shape[1], out_shape[0]), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(np.moveaxis(rgb, -1, 0))


def _tiff_colour_table(page: Any) -> NDArray[np.uint8] | None:
    """A one-band TIFF page's colour map as 8-bit RGB rows (None without one): 16-bit entries
    divided by 257 as GDAL reads them, a map written with 8-bit values (all under 256) as is."""
    cmap = getattr(page, "colormap", None)
    if cmap is None or int(page.samplesperpixel) != 1:
        return None
    cmap = np.asarray(cmap, dtype=np.uint32)[:3]
    cmap = cmap if int(cmap.max(initial=0)) < 256 else cmap // 257
    return np.ascontiguousarray(cmap.T, dtype=np.uint8)


def _read_tifffile(path: Path) -> tuple[NDArray[Any] | None, dict[int, Any], str]:
    """(pixels, GeoTIFF tags, why the pixels are None) read with tifffile; (None, {}, "")
    without it. Pixels are None when tifffile cannot handle the file (not a TIFF to it, a codec
    it lacks: JPEG-compressed TIFFs need the optional imagecodecs; cv2 reads those); a TIFF
    whose compressed data is damaged (a truncated file) is refused naming it."""
    try:
        import tifffile
    except ImportError:
        return None, {}, ""
    tags: dict[int, Any] = {}
    try:
        with tifffile.TiffFile(str(path)) as tif:
            page = tif.pages.first
            tags = grid_tags(page)
            arr = np.asarray(page.asarray())
            table = _tiff_colour_table(page)
    except (ValueError, NotImplementedError, ImportError) as exc:  # TiffFileError is a ValueError
        return None, tags, " ".join(str(exc).split())
    except Exception as exc:  # the codecs' own errors: zlib.error, LZMAError, imagecodecs'
        raise InvalidInputError(
            "path",
            f"{path}: damaged TIFF, its pixel data cannot be decoded "
            f"({type(exc).__name__}: {' '.join(str(exc).split())})",
        ) from exc
    if table is not None and arr.ndim == 2:
        arr = np.moveaxis(expand_palette(arr, table), 0, -1)
    if arr.ndim == 3 and arr.shape[0] in (3, 4) and arr.shape[2] not in (3, 4):
        arr = np.moveaxis(arr, 0, -1)  # planar (bands, H, W)
    return arr, tags, ""


def geotiff_gsd_m(
    tags: dict[int, Any], height_px: int, *, source: str | Path = "the GeoTIFF"
) -> float | None:
    """Ground GSD (m/px, geometric mean of x and y) from raw GeoTIFF tags, or None; a pixel
    scale that is not a north-up grid's, a malformed tag or an unknown linear unit is refused
    naming ``source``. Projected scales are in their CRS's linear unit (the declared
    ProjLinearUnitsGeoKey, else the EPSG code's:
    :func:`~c3_matcher_tools.geodesy.projected_unit`)."""
    scale = pixel_scale(tags, source)
    if scale is None:
        return None
    sx, sy = scale
    keys = geo_keys(tags, source)
    geographic = keys.get(MODEL_TYPE_KEY) == 2
    epsg = keys.get(PROJECTED_CRS_KEY)
    mercator = None if epsg is None else MERCATOR_EPSG.get(int(epsg))
    lat_deg = 0.0  # projected metres need no latitude
    if geographic or mercator is not None:
        tie = tiepoint(tags, source)
        if tie is None:
            return None  # no tie point: no latitude to convert degrees or a Mercator scale at
        centre_y = tie[4] - sy * (height_px / 2.0 - tie[1])
        lat_deg = (
            centre_y
            if geographic
            else float(mercator_latitude_deg(centre_y, ellipsoidal=bool(mercator)))
        )
    unit_m = 1.0
    if not geographic:
        unit_m = projected_unit(epsg, unit_code=keys.get(PROJ_LINEAR_UNITS_KEY), source=source)[1]
    return ground_gsd_m(sx, sy, lat_deg, geographic=geographic, epsg=epsg, unit_m=unit_m)


def load_orthophoto(path: str | Path, *, gsd_m: float | None = None) -> Orthophoto:
    """Load ``path`` as uint8 RGB with its GSD (``gsd_m`` overrides the file's)."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError("path", f"no such file: {p}")
    is_tiff = p.suffix.lower() in (".tif", ".tiff")
    raw, tags, why = _read_tifffile(p) if is_tiff else (None, {}, "")
    if raw is not None:
        arr = raw
        rgb_order = True
    else:
        read = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if read is None:
            raise InvalidInputError("path", f"cannot decode {p}" + (f" ({why})" if why else ""))
        arr = np.asarray(read)
        if is_tiff and arr.ndim == 3 and arr.shape[2] == 4:
            raise InvalidInputError(
                "path",
                f"{p}: 4-band TIFF needs tifffile (OpenCV "
                "premultiplies the colour bands by the 4th); pip install "
                "tifffile",
            )
        rgb_order = False
    alpha = None
    if arr.ndim == 3 and arr.shape[2] >= 4:
        if not is_tiff:
            alpha = arr[..., 3]
        arr = arr[..., :3]
    arr = _to_uint8(arr)
    if arr.ndim == 2:
        converted = cv2.cvtColor(arr, cv2.COLOR_GRAY2RGB)
    elif arr.ndim == 3 and arr.shape[2] == 3:
        converted = arr if rgb_order else cv2.cvtColor(arr, cv2.COLOR_BGR2RGB)
    else:
        raise InvalidInputError("path", f"{p}: unsupported band layout {arr.shape}")
    rgb: NDArray[np.uint8] = np.ascontiguousarray(converted, dtype=np.uint8)
    if alpha is not None:
        rgb[alpha == 0] = 0
    if gsd_m is not None:
        return Orthophoto(rgb, float(gsd_m), p, "given")
    from_tags = geotiff_gsd_m(tags, rgb.shape[0], source=p) if tags else None
    if from_tags is not None:
        return Orthophoto(rgb, from_tags, p, "geotiff")
    if p.name in KNOWN_GSD_M:
        return Orthophoto(rgb, KNOWN_GSD_M[p.name], p, "table")
    return Orthophoto(rgb, None, p, "unknown")
