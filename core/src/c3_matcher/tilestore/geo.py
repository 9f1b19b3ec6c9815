"""Web-mercator pixel math of the tile stores (the flight read path).

WORLD px (X, Y) are web-mercator pixels of 256-px slippy tiles at a zoom ``z`` (corner
convention: the world spans [0, 256 * 2**z) and pixel index i has its centre at X = i + 0.5;
tile (x, y) covers X in [256 x, 256 (x + 1))). Degrees in and out, vectorised over numpy arrays.
GeoTIFF grids and projections are ground tooling (the ground tools' ``tilestore.geo`` and
``tilestore.projection``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64

__all__ = ["MERCATOR_MAX_LAT", "TILE_PX", "lonlat_to_world_px", "world_px_to_lonlat"]

TILE_PX = 256
MERCATOR_MAX_LAT = 85.05112877980659
"""The latitude where web-mercator tiles end (north and south): the square world's edge."""


def lonlat_to_world_px(lonlat: ArrayLike, zoom: int) -> F64:
    """(N, 2) (lon, lat) degrees -> (N, 2) WORLD px (X, Y) at ``zoom`` (corner convention)."""
    q = np.asarray(lonlat, dtype=np.float64).reshape(-1, 2)
    size = TILE_PX * 2.0**zoom
    x = (q[:, 0] + 180.0) / 360.0 * size
    phi = np.radians(q[:, 1])
    y = (1.0 - np.log(np.tan(phi) + 1.0 / np.cos(phi)) / np.pi) / 2.0 * size
    return np.stack([x, y], axis=1)


def world_px_to_lonlat(world: ArrayLike, zoom: int) -> F64:
    """(N, 2) WORLD px (X, Y) at ``zoom`` -> (N, 2) (lon, lat) degrees."""
    p = np.asarray(world, dtype=np.float64).reshape(-1, 2)
    size = TILE_PX * 2.0**zoom
    lon = p[:, 0] / size * 360.0 - 180.0
    lat = np.degrees(np.arctan(np.sinh(np.pi * (1.0 - 2.0 * p[:, 1] / size))))
    return np.stack([lon, lat], axis=1)
