"""Tile-store building (ground tooling): GeoTIFF grids and projections, ``build_mbtiles``
(``c3-matcher tiles build``), ``MBTilesWriter``, and ``c3-matcher tiles info``."""

from __future__ import annotations

from c3_matcher_tools.tilestore.build import BuildReport, build_mbtiles
from c3_matcher_tools.tilestore.geo import GeoGrid, read_geotiff_grid
from c3_matcher_tools.tilestore.projection import Projection
from c3_matcher_tools.tilestore.writer import MBTilesWriter

__all__ = [
    "BuildReport",
    "GeoGrid",
    "MBTilesWriter",
    "Projection",
    "build_mbtiles",
    "read_geotiff_grid",
]
