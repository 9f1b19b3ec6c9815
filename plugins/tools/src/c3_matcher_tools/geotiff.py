"""The GeoTIFF tags a north-up grid is read from, each fact once: the tag and GeoKey ids, the
tags of a ``tifffile`` page, the GeoKeyDirectory's inline keys, the pixel scale and the tie
point (or the model transformation that may stand for both), each checked (a malformed tag,
too short for what it must hold, is refused naming the file, as GDAL refuses it, never an
internal error); a grid that is not north-up is refused as such.

Both GeoTIFF readers build on it (:mod:`c3_matcher_tools.sim.orthophotos` for a frame source's
GSD, :mod:`c3_matcher_tools.tilestore.geo` for a tile store's grid); it imports nothing of the
tools, so each imports it from below.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import InvalidInputError

__all__ = [
    "GEOGRAPHIC_CRS_KEY",
    "GEO_KEY_DIRECTORY",
    "GRID_TAGS",
    "MODEL_TRANSFORMATION",
    "MODEL_TYPE_KEY",
    "PIXEL_SCALE",
    "PROJECTED_CRS_KEY",
    "PROJ_LINEAR_UNITS_KEY",
    "RASTER_TYPE_KEY",
    "TIEPOINT",
    "USER_DEFINED",
    "check_pixel_scale",
    "geo_keys",
    "grid_tags",
    "model_transformation",
    "north_up_scale",
    "pixel_scale",
    "tiepoint",
]

PIXEL_SCALE = 33550
"""ModelPixelScaleTag: (x, y, z) size of a pixel in the CRS's units."""
TIEPOINT = 33922
"""ModelTiepointTag: (i, j, k, x, y, z), raster point (i, j) at CRS point (x, y)."""
MODEL_TRANSFORMATION = 34264
"""ModelTransformationTag: a 4 x 4 matrix (row by row) from raster (i, j) to CRS (x, y), in
place of the pixel scale and tie point; GDAL writes it for a rotated or flipped grid."""
GEO_KEY_DIRECTORY = 34735
"""GeoKeyDirectoryTag: the GeoKeys, four numbers a key after a four-number header."""
GRID_TAGS = (PIXEL_SCALE, TIEPOINT, MODEL_TRANSFORMATION, GEO_KEY_DIRECTORY)

MODEL_TYPE_KEY = 1024
"""GTModelTypeGeoKey: 1 projected, 2 geographic (degrees)."""
RASTER_TYPE_KEY = 1025
"""GTRasterTypeGeoKey: 1 a tie point is a pixel's corner, 2 its centre (RasterPixelIsPoint)."""
GEOGRAPHIC_CRS_KEY = 2048
"""GeographicTypeGeoKey: the EPSG code of a geographic CRS."""
PROJECTED_CRS_KEY = 3072
"""ProjectedCSTypeGeoKey: the EPSG code of a projected CRS."""
USER_DEFINED = 32767
"""A CRS key's value where the CRS is given by its parameters, not by an EPSG code."""
PROJ_LINEAR_UNITS_KEY = 3076
"""ProjLinearUnitsGeoKey: the EPSG code of a projected CRS's linear unit (9001 metre, 9002
foot, 9003 US survey foot)."""


def grid_tags(page: Any) -> dict[int, Any]:
    """The :data:`GRID_TAGS` a ``tifffile`` page holds, by tag id."""
    return {code: page.tags[code].value for code in GRID_TAGS if code in page.tags}


def _malformed(source: str | Path, what: str) -> InvalidInputError:
    return InvalidInputError("geotiff", f"{source}: malformed GeoTIFF: {what}")


def _numbers(
    tags: Mapping[int, Any], code: int, need: int, what: str, source: str | Path
) -> list[float] | None:
    """The numbers of tag ``code`` (None without it); fewer than ``need`` (or text) refused."""
    if code not in tags:
        return None
    try:
        values = [float(v) for v in np.ravel(tags[code])]
    except (TypeError, ValueError):
        values = []
    if len(values) < need:
        raise _malformed(
            source, f"its {what} tag holds {len(values)} number(s), at least {need} needed"
        )
    return values


def pixel_scale(tags: Mapping[int, Any], source: str | Path) -> tuple[float, float] | None:
    """(x, y) of ``tags``' ModelPixelScale, checked (:func:`check_pixel_scale`), or None without
    it; a tag of fewer than two numbers is refused naming ``source``."""
    values = _numbers(tags, PIXEL_SCALE, 2, "ModelPixelScale (x, y, z)", source)
    if values is None:
        return None
    check_pixel_scale(values[0], values[1], source)
    return values[0], values[1]


def tiepoint(tags: Mapping[int, Any], source: str | Path) -> tuple[float, ...] | None:
    """(i, j, k, x, y, z) of ``tags``' first ModelTiepoint, or None without it; a tag of fewer
    than six numbers is refused naming ``source``."""
    values = _numbers(tags, TIEPOINT, 6, "ModelTiepoint (i, j, k, x, y, z)", source)
    return None if values is None else tuple(values[:6])


def model_transformation(
    tags: Mapping[int, Any], source: str | Path
) -> tuple[float, float, float, float, float, float] | None:
    """(a, b, c, d, e, f) of ``tags``' ModelTransformation, ``x = a i + b j + c``,
    ``y = d i + e j + f``, or None without it; a tag of fewer than 8 numbers (its first two
    rows) is refused naming ``source``."""
    values = _numbers(tags, MODEL_TRANSFORMATION, 8, "ModelTransformation (4 x 4 matrix)", source)
    if values is None:
        return None
    return values[0], values[1], values[3], values[4], values[5], values[7]


def geo_keys(tags: Mapping[int, Any], source: str | Path = "the GeoTIFF") -> dict[int, Any]:
    """The inline GeoKeys of ``tags``' GeoKeyDirectory as {key id: value} ({} without one); a
    directory shorter than its header (4 numbers) plus 4 numbers a key it declares is refused
    naming ``source``."""
    if GEO_KEY_DIRECTORY not in tags:
        return {}
    try:
        values = [int(v) for v in np.ravel(tags[GEO_KEY_DIRECTORY])]
    except (TypeError, ValueError):
        values = []
    if len(values) < 4:
        raise _malformed(source, f"its GeoKeyDirectory holds {len(values)} number(s), no header")
    if len(values) < 4 + 4 * values[3]:
        raise _malformed(
            source,
            f"its GeoKeyDirectory declares {values[3]} keys but holds {len(values)} numbers "
            f"({4 + 4 * values[3]} needed: a header of 4 and 4 a key)",
        )
    keys: dict[int, Any] = {}
    for i in range(values[3]):
        key_id, location, _count, value = values[4 + 4 * i : 8 + 4 * i]
        if location == 0:
            keys[key_id] = value
    return keys


def check_pixel_scale(scale_x: float, scale_y: float, source: str | Path) -> None:
    """Refuse a pixel size that is not finite and > 0 on both axes (E to the right, N up): a
    negative one flips the grid (not north-up), zero or NaN is no grid at all."""
    if not all(math.isfinite(s) and s > 0 for s in (scale_x, scale_y)):
        raise InvalidInputError(
            "geotiff",
            f"{source}: not a north-up grid: its pixel size {scale_x:g} x {scale_y:g} (E x N) "
            "must be finite and > 0 on both axes",
        )


def north_up_scale(
    matrix: tuple[float, float, float, float, float, float], source: str | Path
) -> tuple[float, float]:
    """The (x, y) pixel size (E x N) of the affine ``matrix`` (a, b, c, d, e, f):
    ``x = a i + b j + c``, ``y = d i + e j + f``, a ModelTransformation's or GDAL's geotransform;
    a grid that it rotates or shears (b, d not 0) or flips (:func:`check_pixel_scale`) is refused
    naming ``source`` as not north-up."""
    a, b, c, d, e, f = matrix
    if b != 0 or d != 0:
        raise InvalidInputError(
            "geotiff",
            f"{source}: not a north-up grid: its georeference (| {a:g}, {b:g}, {c:,.2f} | {d:g}, "
            f"{e:g}, {f:,.2f} |) rotates or shears it; reproject it north-up first",
        )
    check_pixel_scale(a, -e, source)
    return a, -e
