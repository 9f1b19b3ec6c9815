"""``TileFeatureCache``: features of recently seen tiles, so a tile that stays among the
candidates over consecutive frames (the usual case at 3 Hz) is decoded and extracted once.

Keyed by the tile id AND a digest of the tile's content (its encoded bytes, or for a store's
mosaic the stored tiles it is stitched from): a tile whose pixels change (a store update) is
never served stale. Extraction is deterministic, so a hit gives exactly the
features a fresh extraction would. Least recently used entries are evicted.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass

from c3_matcher.dto import TileId, TilePixelsHandle
from c3_matcher.errors import InvalidInputError
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.protocols import DigestedTileHandle

__all__ = ["CachedTile", "TileFeatureCache", "tile_cache_key"]


@dataclass(frozen=True, slots=True)
class CachedTile:
    prepared: PreparedImage
    features: Features


def tile_cache_key(tile_id: TileId, handle: TilePixelsHandle) -> tuple[TileId, str]:
    """(tile id, digest of the tile's content): a ``DigestedTileHandle``'s ``content_digest()``
    (a store's mosaic: no stitching, no encoding), else blake2b of the encoded bytes read
    through the zero-copy view."""
    if isinstance(handle, DigestedTileHandle):
        return tile_id, handle.content_digest()
    return tile_id, hashlib.blake2b(handle.encoded(), digest_size=16).hexdigest()


class TileFeatureCache:
    """An LRU of ``capacity`` tiles' prepared images and features (0 disables it)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 0:
            raise InvalidInputError("tile_cache_size", f"must be >= 0, got {capacity}")
        self._capacity = capacity
        self._entries: OrderedDict[tuple[TileId, str], CachedTile] = OrderedDict()
        self.hits = 0
        self.misses = 0

    @property
    def enabled(self) -> bool:
        return self._capacity > 0

    def get(self, key: tuple[TileId, str]) -> CachedTile | None:
        entry = self._entries.get(key)
        if entry is None:
            self.misses += 1
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return entry

    def put(self, key: tuple[TileId, str], entry: CachedTile) -> None:
        if not self.enabled:
            return
        self._entries[key] = entry
        self._entries.move_to_end(key)
        while len(self._entries) > self._capacity:
            self._entries.popitem(last=False)

    def discard(self, key: tuple[TileId, str]) -> None:
        """Drop ``key``'s entry, if there is one: features a frame refused, or could not match,
        are extracted anew rather than served again."""
        self._entries.pop(key, None)

    def __len__(self) -> int:
        return len(self._entries)
