"""How an MBTiles store lays out its tiles, as other tools write them: which way its tile rows
count (:func:`rows_from_north`: the metadata ``scheme``, ``tms`` the spec's and the default,
row 0 at the south; ``xyz`` row 0 at the north, as some tools write it), so which stored
``tile_row`` an XYZ row is (:func:`stored_row`, one place for the flip both ways), and how large
its tiles are (:func:`refuse_other_tile_size`: one tile's header, read at open). A store this
reader cannot serve as it is, is refused at open (:class:`StoreFormError`), not tile by tile."""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping
from pathlib import Path
from typing import Final

from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import image_header_size
from c3_matcher.tilestore.geo import TILE_PX

__all__ = [
    "SCHEME_KEY",
    "StoreFormError",
    "first_tile_size",
    "refuse_other_tile_size",
    "rows_from_north",
    "stored_row",
]

SCHEME_KEY: Final = "scheme"
"""The metadata key naming how ``tile_row`` counts: ``tms`` (spec 1.3) or ``xyz``."""

SAMPLED_TILES: Final = 16
"""How many rows are looked at for one tile whose size its header says (NULL, empty and
undecodable blobs are passed over): one tile's header read, a few rows at most."""

_HEAD_BYTES: Final = 65536  # a JPEG's size follows its EXIF and ICC segments: room for them


class StoreFormError(InvalidInputError):
    """An MBTiles store whose tiles are laid out as this reader does not read them (rows
    counted another way, tiles of another size): refused at open, naming what to do."""


def rows_from_north(path: Path, metadata: Mapping[str, str]) -> bool:
    """Whether the store at ``path`` counts its tile rows from the north (metadata ``scheme``
    ``xyz``) rather than from the south (``tms``, the spec's, or no ``scheme``); any other
    ``scheme`` is :class:`StoreFormError` naming it."""
    scheme = metadata.get(SCHEME_KEY)
    if scheme is None or scheme.strip().lower() == "tms":
        return False
    if scheme.strip().lower() == "xyz":
        return True
    shown = scheme if len(scheme) <= 40 else scheme[:37] + "..."
    raise StoreFormError(
        "mbtiles",
        f"{path}: its metadata {SCHEME_KEY!r} is {shown!r}: tile rows are read as 'tms' (row 0"
        " at the south, the MBTiles spec's; the default) or 'xyz' (row 0 at the north); set it"
        " to the one its rows follow",
    )


def stored_row(zoom: int, row: int, from_north: bool) -> int:
    """The other count of tile row ``row`` at ``zoom``: the stored ``tile_row`` of an XYZ row,
    and the XYZ row of a stored one (the TMS flip is its own inverse); unchanged in a store whose
    rows count from the north."""
    return row if from_north else (1 << zoom) - 1 - row


def first_tile_size(db: sqlite3.Connection) -> tuple[tuple[int, int], str] | None:
    """The (width, height) of the first of the first ``SAMPLED_TILES`` rows of the tiles table
    whose header tells it, with that tile's (zoom/column/row as stored); None when none does."""
    query = "SELECT zoom_level, tile_column, tile_row, substr(tile_data, 1, ?) FROM tiles LIMIT ?"
    for z, x, row, head in db.execute(query, (_HEAD_BYTES, SAMPLED_TILES)):
        if isinstance(head, bytes) and head:
            size = image_header_size(head)
            if size is not None:
                return size, f"zoom_level {z}, tile_column {x}, tile_row {row}"
    return None


def refuse_other_tile_size(path: Path, found: tuple[tuple[int, int], str] | None) -> None:
    """Refuse the store at ``path`` whose tile ``found`` (:func:`first_tile_size`) is not
    ``TILE_PX`` square (512-px "retina" tiles: each would be served labelled 256 px, 2x off)."""
    if found is None or found[0] == (TILE_PX, TILE_PX):
        return
    (w, h), which = found
    raise StoreFormError(
        "mbtiles",
        f"{path}: its tiles are {w}x{h} px (the tile at {which}); it reads {TILE_PX}-px"
        f" web-mercator tiles: build the store with {TILE_PX}-px tiles (c3-matcher tiles"
        " build writes them)",
    )
