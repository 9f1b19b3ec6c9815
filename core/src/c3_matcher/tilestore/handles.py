"""Tile pixel handles served by a slippy tile store (:class:`SlippyTileSource`).

A candidate's ``TileId(zoom, lat, lon)`` names the centre of the image the matcher receives.
When that image is exactly one stored tile (the requested size is the store's 256 px and the
centre is that tile's centre) :class:`StoredTileHandle` serves the stored bytes as they are:
``encoded()`` is a view of the blob (for an XYZ folder a read-only memory map of the file:
zero-copy from the page cache; for MBTiles the one copy SQLite hands to Python out of its
memory-mapped database), ``decode()`` decodes it. Otherwise :class:`MosaicTileHandle` stitches
the ``size_px`` x ``size_px`` window of WORLD px centred on the id's centre from the stored
tiles, lazily: nothing is read before the first ``encoded()`` / ``decode()``, the mosaic is
decoded once and kept, and ``encoded()`` is a lossless PNG of it made once. Its
``content_digest()`` names its content from the stored tiles' bytes alone: the tile cache's key,
so that a window seen before is neither stitched nor encoded again.

Failures are the candidate's: a corrupt or undecodable stored tile, or a window with no stored
tile at all, raise from ``encoded()`` / ``decode()``, which the pipeline turns into that
candidate's drop (drop-and-continue). Stored tiles missing at the edge of the coverage
are nodata (0), which the matcher masks.

Pixel limits: ``decode_within(max_pixels)`` (the matcher's ``[matcher] max_image_pixels``:
:mod:`c3_matcher.tile_limit`) refuses a window above it, or one of stored tiles above it, before
any tile is read, and decodes each stored tile under it; ``decode()`` under the default, 50 Mpx.
Either way a stored tile whose header declares another size than 256 px square is refused
before it is decoded.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import (
    DEFAULT_MAX_IMAGE_PIXELS,
    ImageDecodeError,
    decode_image,
    image_header_size,
)
from c3_matcher.tilestore.geo import MERCATOR_MAX_LAT, TILE_PX, lonlat_to_world_px
from c3_matcher.tilestore.windows import covered_tiles, stored_tile_digest, window_digest

if TYPE_CHECKING:
    from c3_matcher.features import Features
    from c3_matcher.tilestore.features import FeatureRequest, NoStoredSet

__all__ = [
    "MosaicTileHandle",
    "SlippyTileSource",
    "StoredTileHandle",
    "TileNotFoundError",
    "mosaic_origin",
    "stitch",
]


class TileNotFoundError(InvalidInputError):
    """The store holds no tile for the requested id / window."""


NO_TILE_IN_WINDOW = "no stored tile overlaps this window"


class SlippyTileSource(Protocol):
    """A store of 256-px web-mercator tiles addressed (zoom, x, y), XYZ (y grows south)."""

    @property
    def name(self) -> str: ...

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None:
        """The encoded tile, or None when the store has no such tile."""
        ...


def mosaic_origin(tile_id: TileId, size_px: int) -> tuple[int, int]:
    """WORLD px index of the top-left pixel of the ``size_px`` window centred on ``tile_id``:
    TILE px (u, v) of the served image is WORLD px (X0 + u + 0.5, Y0 + v + 0.5). A centre beyond
    the tiles' latitude limit is refused (InvalidInputError): no tile covers it."""
    if abs(tile_id.lat) > MERCATOR_MAX_LAT:
        raise InvalidInputError(
            "tile_id.lat",
            f"{tile_id.lat} is beyond the web-mercator tiles' limit, +-{MERCATOR_MAX_LAT:.4f} deg",
        )
    (cx, cy) = lonlat_to_world_px([[tile_id.lon, tile_id.lat]], tile_id.zoom)[0]
    return math.floor(cx - size_px / 2 + 0.5), math.floor(cy - size_px / 2 + 0.5)


class StoredTileHandle:
    """One stored tile's bytes, served as they are (see the module docstring)."""

    def __init__(self, source: SlippyTileSource, zoom: int, x: int, y: int) -> None:
        self._source, self._key = source, (zoom, x, y)
        self._blob: memoryview | None = None
        self._pixels: NDArray[np.uint8] | None = None

    def encoded(self) -> memoryview:
        if self._blob is None:
            blob = self._source.tile_bytes(*self._key)
            if blob is None:
                raise TileNotFoundError(self._what(), "no such tile in the store")
            self._blob = blob
        return self._blob

    def decode(self) -> NDArray[np.uint8]:
        return self.decode_within(DEFAULT_MAX_IMAGE_PIXELS)

    def decode_within(self, max_pixels: int) -> NDArray[np.uint8]:
        """``decode()`` refusing a tile above ``max_pixels`` (width x height) before decoding."""
        _refuse_above(TILE_PX, max_pixels, self._what())
        if self._pixels is None:
            self._pixels = _tile_pixels(self.encoded(), self._what(), max_pixels)
        return self._pixels.copy()

    def stored_features(self, request: FeatureRequest) -> Features | None:
        """This tile's features from the store's precomputed map features (tile px), or None:
        see :func:`c3_matcher.tilestore.features.served_window`."""
        from c3_matcher.tilestore.features import features_only

        return features_only(self.stored_window(request))

    def stored_window(self, request: FeatureRequest) -> Features | NoStoredSet | None:
        """:meth:`stored_features`, or why there are none when the store's sidecar holds no
        set for ``request``: :func:`c3_matcher.tilestore.features.served_window`."""
        z, x, y = self._key
        return _stored_window(self._source, request, z, (x * TILE_PX, y * TILE_PX), TILE_PX)

    def _what(self) -> str:
        z, x, y = self._key
        return f"{self._source.name} tile {z}/{x}/{y}"

    def __repr__(self) -> str:
        return f"StoredTileHandle({self._what()!r})"


class MosaicTileHandle:
    """A ``size_px`` square window of WORLD px centred on a tile id, stitched from stored tiles
    (see the module docstring)."""

    def __init__(self, source: SlippyTileSource, tile_id: TileId, size_px: int) -> None:
        if size_px < 16:
            raise InvalidInputError("size_px", f"must be >= 16, got {size_px}")
        self._source, self._tile_id, self._size = source, tile_id, int(size_px)
        self._pixels: NDArray[np.uint8] | None = None
        self._png: bytes | None = None

    @property
    def origin_world_px(self) -> tuple[int, int]:
        return mosaic_origin(self._tile_id, self._size)

    def encoded(self) -> memoryview:
        if self._png is None:
            ok, buf = cv2.imencode(".png", self._mosaic()[:, :, ::-1])
            if not ok:
                raise InvalidInputError(self._what(), "PNG encoding of the mosaic failed")
            self._png = buf.tobytes()
        return memoryview(self._png)

    def decode(self) -> NDArray[np.uint8]:
        return self.decode_within(DEFAULT_MAX_IMAGE_PIXELS)

    def decode_within(self, max_pixels: int) -> NDArray[np.uint8]:
        """``decode()`` refusing a window above ``max_pixels`` (width x height), or one whose
        stored tiles are, before any tile is read."""
        _refuse_above(self._size, max_pixels, self._what())
        _refuse_above(TILE_PX, max_pixels, f"{self._what()}: each of its stored tiles")
        return self._mosaic(max_pixels).copy()

    def content_digest(self) -> str:
        """The window's size and :func:`~c3_matcher.tilestore.windows.window_digest` of the
        stored tiles it covers, read anew: the mosaic's pixels depend on these alone, so it
        changes whenever they do, and nothing is stitched or encoded. Raises as ``decode()``
        does when no stored tile overlaps the window."""
        origin, size = self.origin_world_px, (self._size, self._size)
        found: list[bool] = []

        def digest_of(key: tuple[int, int, int]) -> str | None:
            digest = stored_tile_digest(self._source, key)
            found.append(digest is not None)
            return digest

        digest = window_digest(covered_tiles(self._tile_id.zoom, origin, size), digest_of)
        if not any(found):
            raise TileNotFoundError(self._what(), NO_TILE_IN_WINDOW)
        return f"{self._size}:{digest}"

    def stored_features(self, request: FeatureRequest) -> Features | None:
        """The window's features from the store's precomputed map features (window
        px), or None: see :func:`c3_matcher.tilestore.features.served_window`."""
        from c3_matcher.tilestore.features import features_only

        return features_only(self.stored_window(request))

    def stored_window(self, request: FeatureRequest) -> Features | NoStoredSet | None:
        """:meth:`stored_features`, or why there are none when the store's sidecar holds no
        set for ``request``: :func:`c3_matcher.tilestore.features.served_window`."""
        return _stored_window(
            self._source, request, self._tile_id.zoom, self.origin_world_px, self._size
        )

    def _mosaic(self, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS) -> NDArray[np.uint8]:
        if self._pixels is None:
            size, zoom = (self._size, self._size), self._tile_id.zoom
            self._pixels = stitch(
                self._source, zoom, self.origin_world_px, size, self._what(), max_pixels
            )
        return self._pixels

    def _what(self) -> str:
        return f"{self._source.name} mosaic {self._size}px at {self._tile_id}"

    def __repr__(self) -> str:
        return f"MosaicTileHandle({self._what()!r})"


def _stored_window(
    source: SlippyTileSource,
    request: FeatureRequest,
    zoom: int,
    origin: tuple[int, int],
    size_px: int,
) -> Features | NoStoredSet | None:
    from c3_matcher.tilestore.features import FeatureSource, served_window

    if not isinstance(source, FeatureSource):
        return None  # a store without precomputed features (its optional ``feature_store``)
    return served_window(source, request, zoom, origin, (size_px, size_px))


def stitch(
    source: SlippyTileSource,
    zoom: int,
    origin: tuple[int, int],
    size: tuple[int, int],
    what: str,
    max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS,
) -> NDArray[np.uint8]:
    """The (w, h) = ``size`` window of WORLD px whose top-left pixel index is ``origin`` at
    ``zoom``, uint8 RGB; missing tiles are 0 (nodata). Raises TileNotFoundError when no stored
    tile overlaps the window, ImageDecodeError for an undecodable one (or one above
    ``max_pixels``: :func:`_tile_pixels`)."""
    x0, y0 = int(origin[0]), int(origin[1])
    w, h = int(size[0]), int(size[1])
    out = np.zeros((h, w, 3), dtype=np.uint8)
    found = 0
    n = 2**zoom
    for ty in range(y0 // TILE_PX, (y0 + h - 1) // TILE_PX + 1):
        for tx in range(x0 // TILE_PX, (x0 + w - 1) // TILE_PX + 1):
            if not 0 <= ty < n:
                continue
            blob = source.tile_bytes(zoom, tx % n, ty)
            if blob is None:
                continue
            name = f"{source.name} tile {zoom}/{tx % n}/{ty}"
            tile = _tile_pixels(blob, name, max_pixels)
            found += 1
            ax, ay = tx * TILE_PX, ty * TILE_PX
            sx0, sy0 = max(x0, ax), max(y0, ay)
            sx1, sy1 = min(x0 + w, ax + TILE_PX), min(y0 + h, ay + TILE_PX)
            out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = tile[
                sy0 - ay : sy1 - ay, sx0 - ax : sx1 - ax
            ]
    if found == 0:
        raise TileNotFoundError(what, NO_TILE_IN_WINDOW)
    return out


def _refuse_above(side: int, max_pixels: int, what: str) -> None:
    """ImageDecodeError naming ``what``, a ``side`` px square, when it is above ``max_pixels``."""
    if side * side > max_pixels:
        raise ImageDecodeError(
            what,
            f"{side}x{side} px exceeds the limit of {max_pixels} px ([matcher] "
            "max_image_pixels); refused before decoding",
        )


def _tile_pixels(
    blob: memoryview, name: str, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
) -> NDArray[np.uint8]:
    """The stored tile ``blob`` (``name``) decoded within ``max_pixels``, uint8 RGB;
    InvalidInputError unless it is TILE_PX x TILE_PX (a store of other tiles would serve them
    labelled as TILE_PX px), from its header before decoding where that says its size."""
    declared = image_header_size(blob)
    if declared is not None and declared != (TILE_PX, TILE_PX):
        raise InvalidInputError(
            name,
            f"expected {TILE_PX}x{TILE_PX} px, got {declared[0]}x{declared[1]} (its header"
            " says so: refused before decoding)",
        )
    tile = decode_image(blob, name, max_pixels)
    if tile.shape[:2] != (TILE_PX, TILE_PX):
        raise InvalidInputError(
            name, f"expected {TILE_PX}x{TILE_PX} px, got {tile.shape[1]}x{tile.shape[0]}"
        )
    return tile
