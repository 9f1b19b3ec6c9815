"""Tile stores (the C6 side C3 consumes): MBTiles and XYZ folders of 256-px web-mercator tiles,
served to the matcher as lazy ``TilePixelsHandle``s keyed by the composite tile id
(zoom, lat, lon), mosaicked around the id's centre at a configured size; ``build_mbtiles``
makes a store from a georeferenced orthophoto (``c3-matcher tiles build``)."""

from __future__ import annotations

from c3_matcher.tilestore.base import DEFAULT_CANDIDATE_PX, TileStoreBase, tile_centre_id
from c3_matcher.tilestore.build import BuildReport, build_mbtiles
from c3_matcher.tilestore.geo import GeoGrid, Projection, read_geotiff_grid
from c3_matcher.tilestore.handles import MosaicTileHandle, StoredTileHandle, TileNotFoundError
from c3_matcher.tilestore.mbtiles import MBTilesStore, MBTilesWriter
from c3_matcher.tilestore.xyz import XyzTileStore

__all__ = [
    "DEFAULT_CANDIDATE_PX",
    "BuildReport",
    "GeoGrid",
    "MBTilesStore",
    "MBTilesWriter",
    "MosaicTileHandle",
    "Projection",
    "StoredTileHandle",
    "TileNotFoundError",
    "TileStoreBase",
    "XyzTileStore",
    "build_mbtiles",
    "read_geotiff_grid",
    "tile_centre_id",
]
