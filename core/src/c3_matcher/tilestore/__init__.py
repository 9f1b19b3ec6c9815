"""Tile stores (the C6 side C3 consumes, flight read path): MBTiles and XYZ folders of 256-px
web-mercator tiles, served to the matcher as lazy ``TilePixelsHandle``s keyed by the composite
tile id (zoom, lat, lon), mosaicked around the id's centre at a configured size. Building a
store from an orthophoto is ground tooling (``c3-matcher tiles build``, c3-matcher-tools)."""

from __future__ import annotations

from c3_matcher.tilestore.base import DEFAULT_CANDIDATE_PX, TileStoreBase, tile_centre_id
from c3_matcher.tilestore.handles import MosaicTileHandle, StoredTileHandle, TileNotFoundError
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.tilestore.xyz import XyzTileStore

__all__ = [
    "DEFAULT_CANDIDATE_PX",
    "MBTilesStore",
    "MosaicTileHandle",
    "StoredTileHandle",
    "TileNotFoundError",
    "TileStoreBase",
    "XyzTileStore",
    "tile_centre_id",
]
