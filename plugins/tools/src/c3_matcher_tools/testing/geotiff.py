"""GeoTIFFs written tag by tag for tests: any pixel scale, CRS or raster type, which GDAL would
not always write (a negative scale, a grid the shipped imagery lacks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from c3_matcher_tools.geotiff import (
    GEO_KEY_DIRECTORY,
    MODEL_TYPE_KEY,
    PIXEL_SCALE,
    PROJECTED_CRS_KEY,
    RASTER_TYPE_KEY,
    TIEPOINT,
)

__all__ = ["projected_keys", "write_geotiff"]


def projected_keys(epsg: int) -> tuple[int, ...]:
    """The GeoKeyDirectory of the projected CRS ``epsg``, tie points at pixel corners."""
    return (
        1,
        1,
        0,
        3,
        MODEL_TYPE_KEY,
        0,
        1,
        1,
        RASTER_TYPE_KEY,
        0,
        1,
        1,
        PROJECTED_CRS_KEY,
        0,
        1,
        epsg,
    )


def write_geotiff(
    path: Path,
    image: NDArray[np.uint8],
    *,
    scale: tuple[float, float],
    top_left: tuple[float, float],
    keys: tuple[int, ...],
    compression: str | None = None,
) -> Path:
    """``image`` (RGB) at ``path``: its top-left corner at CRS point ``top_left``, ``scale``
    CRS units per pixel (x, y), ``keys`` its GeoKeyDirectory."""
    import tifffile

    tifffile.imwrite(
        path,
        image,
        photometric="rgb",
        compression=compression,
        extratags=[
            (PIXEL_SCALE, "d", 3, (*scale, 0.0), True),
            (TIEPOINT, "d", 6, (0.0, 0.0, 0.0, *top_left, 0.0), True),
            (GEO_KEY_DIRECTORY, "H", len(keys), keys, True),
        ],
    )
    return path
