"""``MBTilesWriter``: create an MBTiles store (spec 1.3; the schema the flight read path,
``c3_matcher.tilestore.mbtiles.MBTilesStore``, reads)."""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Mapping
from pathlib import Path

from c3_matcher.errors import InvalidInputError

__all__ = ["MBTilesWriter"]

_SCHEMA = (
    "CREATE TABLE metadata (name TEXT, value TEXT)",
    "CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,"
    " tile_data BLOB)",
    "CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)",
    "CREATE UNIQUE INDEX name ON metadata (name)",
    # per-tile digest (issue 11): the read path verifies it and drops a tile that fails
    "CREATE TABLE c3_tile_digest (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,"
    " sha256 TEXT)",
    "CREATE UNIQUE INDEX c3_tile_digest_index ON c3_tile_digest (zoom_level, tile_column,"
    " tile_row)",
)


class MBTilesWriter:
    """Create a new MBTiles file (refuses to overwrite an existing one unless ``overwrite``)."""

    def __init__(self, path: str | Path, *, overwrite: bool = False) -> None:
        self._path = Path(path)
        if self._path.exists():
            if not overwrite:
                raise InvalidInputError("mbtiles", f"{self._path} exists (use --force)")
            self._path.unlink()
        self._path.parent.mkdir(parents=True, exist_ok=True)
        self._db = sqlite3.connect(str(self._path))
        for statement in _SCHEMA:
            self._db.execute(statement)

    def put_tile(self, zoom: int, x: int, y: int, data: bytes) -> None:
        """Store XYZ tile (zoom, x, y) (converted to a TMS row) and its sha256."""
        row = (1 << zoom) - 1 - y
        self._db.execute(
            "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?)",
            (zoom, x, row, sqlite3.Binary(data)),
        )
        self._db.execute(
            "INSERT OR REPLACE INTO c3_tile_digest VALUES (?, ?, ?, ?)",
            (zoom, x, row, hashlib.sha256(data).hexdigest()),
        )

    def put_metadata(self, values: Mapping[str, object]) -> None:
        for key, value in values.items():
            text = value if isinstance(value, str) else json.dumps(value)
            self._db.execute("INSERT OR REPLACE INTO metadata VALUES (?, ?)", (key, text))

    def close(self) -> None:
        self._db.commit()
        self._db.execute("VACUUM")
        self._db.close()

    def __enter__(self) -> MBTilesWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
