"""MBTiles (the SQLite tile format GDAL and QGIS write, spec 1.3): read and write.

Schema (spec 1.3)::

    CREATE TABLE metadata (name TEXT, value TEXT);
    CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,
                        tile_data BLOB);
    CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row);

Tiles are 256-px web-mercator tiles; ``tile_row`` is TMS (row 0 at the south), so XYZ ``y`` is
``2**zoom - 1 - tile_row``. Metadata holds the spec's ``name``, ``format`` (png|jpg), ``bounds``,
``center``, ``minzoom``, ``maxzoom``, ``type`` plus, for stores built by ``c3-matcher tiles
build``, ``c3_source`` (the GeoTIFF), ``c3_georeference`` (how its grid was converted to
WGS84, JSON of :class:`~c3_matcher.tilestore.geo.Projection`) and ``c3_source_gsd_m``.

Reading opens the database read-only with SQLite memory-mapped I/O (``PRAGMA mmap_size``): the
database pages are served from the page cache through a mapping, not ``read()`` into SQLite's
own cache; each tile blob reaches Python as one ``bytes`` (the sqlite3 module's only way) and
handles expose it as a ``memoryview`` without further copies. A database error while reading a
tile (a corrupt page) is raised as that tile's error, never a crash of the caller.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator, Mapping
from pathlib import Path

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.base import TileStoreBase

__all__ = ["MBTilesStore"]

MMAP_BYTES = 256 * 1024 * 1024


class MBTilesStore(TileStoreBase):
    """A read-only MBTiles store (see the module docstring). ``close()`` when done."""

    def __init__(self, path: str | Path, *, mmap_bytes: int = MMAP_BYTES) -> None:
        self._path = Path(path)
        if not self._path.is_file():
            raise InvalidInputError("mbtiles", f"no such file: {self._path}")
        try:
            self._db = sqlite3.connect(f"file:{self._path.resolve()}?mode=ro", uri=True)
            self._db.execute(f"PRAGMA mmap_size={int(mmap_bytes)}")
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master")}
        except sqlite3.DatabaseError as exc:
            raise InvalidInputError(
                "mbtiles", f"{self._path}: not an SQLite database: {exc}"
            ) from exc
        missing = {"metadata", "tiles"} - tables
        if missing:
            self._db.close()
            raise InvalidInputError(
                "mbtiles", f"{self._path}: not an MBTiles file (missing tables {sorted(missing)})"
            )
        self._metadata = {
            str(k): str(v) for k, v in self._db.execute("SELECT name, value FROM metadata")
        }

    @property
    def name(self) -> str:
        return self._path.name

    @property
    def path(self) -> Path:
        return self._path

    @property
    def metadata(self) -> Mapping[str, str]:
        return dict(self._metadata)

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None:
        """The encoded XYZ tile (zoom, x, y), or None when absent; a database error is raised
        as InvalidInputError naming the tile."""
        row = (1 << zoom) - 1 - y
        try:
            found = self._db.execute(
                "SELECT tile_data FROM tiles WHERE zoom_level=? AND tile_column=? AND tile_row=?",
                (zoom, x, row),
            ).fetchone()
        except sqlite3.DatabaseError as exc:
            raise InvalidInputError(
                f"{self.name} tile {zoom}/{x}/{y}", f"read failed: {exc}"
            ) from exc
        if found is None or found[0] is None:
            return None
        return memoryview(found[0])

    def zooms(self) -> list[int]:
        return [
            int(r[0]) for r in self._db.execute("SELECT DISTINCT zoom_level FROM tiles ORDER BY 1")
        ]

    def tiles(self, zoom: int) -> Iterator[tuple[int, int]]:
        """XYZ (x, y) of every stored tile at ``zoom``."""
        n = 1 << zoom
        for col, row in self._db.execute(
            "SELECT tile_column, tile_row FROM tiles WHERE zoom_level=? ORDER BY 2 DESC, 1", (zoom,)
        ):
            yield int(col), n - 1 - int(row)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> MBTilesStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"MBTilesStore({str(self._path)!r})"
