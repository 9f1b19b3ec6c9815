"""The GeoTIFF tags a north-up grid is read from, each fact once: the tag and GeoKey ids, the
tags of a ``tifffile`` page, the GeoKeyDirectory's inline keys, and the check of a pixel scale.

Both GeoTIFF readers build on it (:mod:`c3_matcher_tools.sim.orthophotos` for a frame source's
GSD, :mod:`c3_matcher_tools.tilestore.geo` for a tile store's grid); it imports nothing of the
tools, so each imports it from below.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from c3_matcher.errors import InvalidInputError

__all__ = [
    "GEOGRAPHIC_CRS_KEY",
    "GEO_KEY_DIRECTORY",
    "GRID_TAGS",
    "MODEL_TYPE_KEY",
    "PIXEL_SCALE",
    "PROJECTED_CRS_KEY",
    "RASTER_TYPE_KEY",
    "TIEPOINT",
    "check_pixel_scale",
    "geo_keys",
    "grid_tags",
]

PIXEL_SCALE = 33550
"""ModelPixelScaleTag: (x, y, z) size of a pixel in the CRS's units."""
TIEPOINT = 33922
"""ModelTiepointTag: (i, j, k, x, y, z), raster point (i, j) at CRS point (x, y)."""
GEO_KEY_DIRECTORY = 34735
"""GeoKeyDirectoryTag: the GeoKeys, four numbers a key after a four-number header."""
GRID_TAGS = (PIXEL_SCALE, TIEPOINT, GEO_KEY_DIRECTORY)

MODEL_TYPE_KEY = 1024
"""GTModelTypeGeoKey: 1 projected, 2 geographic (degrees)."""
RASTER_TYPE_KEY = 1025
"""GTRasterTypeGeoKey: 1 a tie point is a pixel's corner, 2 its centre (RasterPixelIsPoint)."""
GEOGRAPHIC_CRS_KEY = 2048
"""GeographicTypeGeoKey: the EPSG code of a geographic CRS."""
PROJECTED_CRS_KEY = 3072
"""ProjectedCSTypeGeoKey: the EPSG code of a projected CRS."""


def grid_tags(page: Any) -> dict[int, Any]:
    """The :data:`GRID_TAGS` a ``tifffile`` page holds, by tag id."""
    return {code: page.tags[code].value for code in GRID_TAGS if code in page.tags}


def geo_keys(tags: Mapping[int, Any]) -> dict[int, Any]:
    """The inline GeoKeys of ``tags``' GeoKeyDirectory as {key id: value} ({} without one)."""
    if GEO_KEY_DIRECTORY not in tags:
        return {}
    values = [int(v) for v in tags[GEO_KEY_DIRECTORY]]
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
