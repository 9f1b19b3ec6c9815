"""What every slippy tile store offers on top of ``tile_bytes``: candidate handles by tile id."""

from __future__ import annotations

from c3_matcher.dto import RerankCandidate, TileId, TilePixelsHandle
from c3_matcher.tilestore.geo import TILE_PX, world_px_to_lonlat
from c3_matcher.tilestore.handles import (
    MosaicTileHandle,
    SlippyTileSource,
    StoredTileHandle,
    mosaic_origin,
)

__all__ = ["DEFAULT_CANDIDATE_PX", "TileStoreBase", "tile_centre_id"]

DEFAULT_CANDIDATE_PX = 256


def tile_centre_id(zoom: int, x: int, y: int) -> TileId:
    """The composite id (zoom, lat, lon) of slippy tile (zoom, x, y): its centre."""
    lon, lat = world_px_to_lonlat([[(x + 0.5) * TILE_PX, (y + 0.5) * TILE_PX]], zoom)[0]
    return TileId(zoom, float(lat), float(lon))


class TileStoreBase:
    """Mixin for a :class:`SlippyTileSource`: ``handle`` / ``candidate`` by composite tile id."""

    def handle(
        self: SlippyTileSource, tile_id: TileId, size_px: int = DEFAULT_CANDIDATE_PX
    ) -> TilePixelsHandle:
        """A lazy handle on the ``size_px`` square image centred on ``tile_id`` (its zoom picks
        the level): the stored tile itself when it is exactly one, else a mosaic."""
        x0, y0 = mosaic_origin(tile_id, size_px)
        if size_px == TILE_PX and x0 % TILE_PX == 0 and y0 % TILE_PX == 0:
            return StoredTileHandle(self, tile_id.zoom, x0 // TILE_PX, y0 // TILE_PX)
        return MosaicTileHandle(self, tile_id, size_px)

    def candidate(
        self: SlippyTileSource,
        tile_id: TileId,
        score: float = 1.0,
        size_px: int = DEFAULT_CANDIDATE_PX,
    ) -> RerankCandidate:
        """A RerankCandidate for ``tile_id`` whose GSD is the web-mercator ground GSD at its
        latitude (m/px)."""
        handle = TileStoreBase.handle(self, tile_id, size_px)
        return RerankCandidate(tile_id, score, handle, tile_id.web_mercator_gsd_m())
