"""An MBTiles store file as a running store (:class:`~c3_matcher.tilestore.mbtiles.
MBTilesStore`) reads it: its shape checked and what reading it once decides
(:class:`StoreFile`: its metadata, whether its tiles carry sha256 digests, so which query reads
a tile); which file that was (:class:`FileIdentity`) and when to look again whether the path
names another file, or the file was rewritten (:class:`FollowedFile`); a tile's row checked
against its digest and its type (:func:`verified_tile`); whether the whole store still answers
(:func:`probe_failure`)."""

from __future__ import annotations

import hashlib
import sqlite3
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final, NamedTuple

from c3_matcher._validate import finite_float, whole_number
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.bounded import OPEN_S, READ_S, BoundedConnection
from c3_matcher.tilestore.files import connect_read_only
from c3_matcher.tilestore.mbtiles_form import (
    StoreFormError,
    first_tile_size,
    refuse_other_tile_size,
    rows_from_north,
    stored_row,
)

__all__ = [
    "CHECK_S",
    "FileIdentity",
    "FollowedFile",
    "StoreFile",
    "TileDigestError",
    "file_identity",
    "holds",
    "probe_failure",
    "read_store_file",
    "refusal",
    "stored_xyz",
    "stored_zooms",
    "verified_tile",
]


class TileDigestError(InvalidInputError):
    """A tile's bytes do not match the sha256 the store recorded when it was built."""


class FileIdentity(NamedTuple):
    """Which file a path names and how it stands (``os.stat``): another file (a rename over
    the path) has another device or inode; a rewrite in place, another size or mtime."""

    device: int
    inode: int
    size: int
    mtime_ns: int


def file_identity(path: Path) -> FileIdentity | None:
    """The identity of the file ``path`` names now; None when it cannot be stat-ed (removed)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return FileIdentity(st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


_DIGEST_QUERY: Final = (
    "SELECT t.tile_data, d.sha256 FROM tiles t LEFT JOIN c3_tile_digest d"
    " ON d.zoom_level=t.zoom_level AND d.tile_column=t.tile_column AND d.tile_row=t.tile_row"
    " WHERE t.zoom_level=? AND t.tile_column=? AND t.tile_row=?"
)
_PLAIN_QUERY: Final = (
    "SELECT t.tile_data, NULL FROM tiles t"
    " WHERE t.zoom_level=? AND t.tile_column=? AND t.tile_row=?"
)


@dataclass(frozen=True)
class StoreFile:
    """What reading the store file once decided. ``identity`` is the file's when it was read
    (None: the file at the path could not be read as a store, so every later look reads it
    again); ``query`` reads one tile's (blob, sha256 or NULL) by (zoom, column, stored row);
    ``rows_from_north``: its rows are XYZ rows (metadata ``scheme`` ``xyz``), not TMS ones;
    ``tile_size``: (width, height) of the tile whose header was read at open, None when none
    told it; ``refused``: why the file now at the path is not read (a form open refuses), so
    that every read says so rather than reading it as the file before it was."""

    identity: FileIdentity | None
    metadata: Mapping[str, str]
    has_digests: bool
    rows_from_north: bool = False
    tile_size: tuple[int, int] | None = None
    refused: StoreFormError | None = None

    @property
    def query(self) -> str:
        if self.refused is not None:
            raise StoreFormError(self.refused.field, self.refused.reason)
        return _DIGEST_QUERY if self.has_digests else _PLAIN_QUERY


def read_store_file(
    path: Path, identity: FileIdentity | None, *, timeout: float, bound: float = OPEN_S
) -> StoreFile | str:
    """The store file ``path`` (whose identity, taken before, is ``identity``) read once on a
    connection of its own, closed after: a :class:`StoreFile`, or why it is no MBTiles store
    (a table or a column missing, a zoom_level that is no zoom). Raises SQLite's error when
    it cannot be read (locked, damaged, not an SQLite database), QueryTimeoutError when it
    does not answer within ``bound`` seconds (a ``tiles`` view that never ends: ``OPEN_S`` at
    open, ``READ_S`` when a running store reads a changed file, on a frame's thread), and
    StoreFormError for a store laid out as it is not read (:mod:`~c3_matcher.tilestore.
    mbtiles_form`: an unknown ``scheme``, tiles not 256 px)."""
    db = connect_read_only(path, timeout=timeout)
    try:
        with db.within(bound, "reading its tables as at open"):
            tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master")}
            wrong = _not_mbtiles(db, tables)
            if wrong is not None:
                return wrong
            rows = db.execute("SELECT name, value FROM metadata")
            metadata = {str(k): str(v) for k, v in rows}
        from_north = rows_from_north(path, metadata)
        size = _sampled_tile_size(db, bound)
    finally:
        db.close()
    refuse_other_tile_size(path, size)
    tile_size = None if size is None else size[0]
    return StoreFile(identity, metadata, "c3_tile_digest" in tables, from_north, tile_size)


def _sampled_tile_size(db: BoundedConnection, bound: float) -> tuple[tuple[int, int], str] | None:
    """:func:`~c3_matcher.tilestore.mbtiles_form.first_tile_size` within ``bound`` seconds, at
    most ``READ_S`` (a tile's read); None when a damaged page holds those tiles or their data
    is not read in time (a view's): each tile's own error when it is read, as before."""
    try:
        with db.within(min(bound, READ_S), "reading one tile's header"):
            return first_tile_size(db)
    except sqlite3.DatabaseError:  # QueryTimeoutError included
        return None


CHECK_S: Final = 1.0  # a running store looks at its file again (changed?) at most this often
LOCK_WAIT_S: Final = 0.05  # SQLite busy timeout of a read: a commit elsewhere, never a held lock


class FollowedFile:
    """A running store's file as last read (``current``), looked at again at most every
    ``check_s`` seconds of ``clock`` (:meth:`due`) and read again when it changed
    (:meth:`look`); any thread may call either."""

    def __init__(
        self, path: Path, current: StoreFile, *, check_s: float, clock: Callable[[], float]
    ) -> None:
        self._path, self.current = path, current
        self._check_s = finite_float(check_s, "check_s", low=0.0)
        self._clock = clock
        self._check_at = clock() + self._check_s
        self._lock = threading.Lock()  # one thread reads a changed file at a time

    def due(self) -> bool:
        """Whether ``check_s`` has passed since the last look (the next one counts from now)."""
        now = self._clock()
        if now < self._check_at:
            return False
        self._check_at = now + self._check_s
        return True

    def look(self) -> StoreFile | None:
        """The file read again, now ``current``, when the path names another file than was
        read or the file changed; None when it did not, or is removed (left as it is), or
        cannot be read as a store within ``READ_S`` now (emptied, half-written, a view that
        never ends: ``current`` then carries that file's identity, so every thread reads the
        file as it stands, and the file is read again once it changes again: a frame waits on
        such a file at most ``READ_S`` a change)."""
        with self._lock:
            identity = file_identity(self._path)
            if identity is None or identity == self.current.identity:
                return None
            try:
                found = read_store_file(self._path, identity, timeout=LOCK_WAIT_S, bound=READ_S)
            except StoreFormError as exc:  # laid out as it is not read: every read says so
                self.current = replace(self.current, identity=identity, refused=exc)
                return None
            except sqlite3.Error:
                found = "unreadable"
            if isinstance(found, str):
                self.current = replace(self.current, identity=identity, refused=None)
                return None
            self.current = found
            return found


_SQL_TYPES: Final = {str: "TEXT", int: "an INTEGER", float: "a REAL"}
"""The SQL type of a value the sqlite3 module hands over, as a tile_data of it is said."""


def verified_tile(found: tuple[object, object] | None, what: str) -> memoryview | None:
    """The blob of the tile row ``found`` (blob, sha256 or None) of the tile ``what``, checked
    against its sha256 when one is stored (TileDigestError when it fails); None for no row,
    or an empty row (NULL or 0 bytes, as other tools store a blank tile) without a sha256,
    or 0 bytes whose sha256 is that of 0 bytes (it was blank when digested): no tile. A
    tile_data that is no BLOB (TEXT, a number) is InvalidInputError naming ``what``."""
    if found is None:
        return None
    blob, digest = found
    if blob is None:
        if digest is None:
            return None
        raise TileDigestError(what, "its data is NULL but a sha256 is stored: the tile is lost")
    if not isinstance(blob, bytes):
        kind = _SQL_TYPES.get(type(blob), type(blob).__name__)
        raise InvalidInputError(what, f"its tile_data is {kind}, not a BLOB of encoded image bytes")
    if digest is not None and hashlib.sha256(blob).hexdigest() != digest:
        raise TileDigestError(
            what, f"sha256 mismatch (stored {str(digest)[:16]}...): the tile is corrupt"
        )
    return memoryview(blob) if len(blob) else None


_OTHER_TILE: Final = (
    "SELECT zoom_level, tile_column, tile_row FROM tiles"
    " WHERE NOT (zoom_level=? AND tile_column=? AND tile_row=?) LIMIT 1"
)
"""The key of a tile other than a given one: the first of the spec's tile index where the store
has it (which holds every key: no row of the tiles table is read to find it)."""


def probe_failure(
    path: Path, *, timeout: float, failed: tuple[int, int, int] | None = None
) -> sqlite3.Error | None:
    """SQLite's error when a fresh connection cannot read the store file ``path`` (its
    metadata, then a tile other than the one whose read ``failed``, its stored (zoom, column,
    row), each within ``READ_S``), so the whole store is unusable; None when it answers: a
    failure only the failed tile's own row gives (a damaged record) stays that tile's."""
    try:
        probe = connect_read_only(path, timeout=timeout)
        try:
            with probe.within(READ_S, "reading its metadata"):
                probe.execute("SELECT count(*) FROM metadata").fetchone()
            with probe.within(READ_S, "reading a tile"):
                other = probe.execute(_OTHER_TILE, failed or (-1, -1, -1)).fetchone()
                if other is not None:
                    probe.execute(_PLAIN_QUERY, other).fetchone()
        finally:
            probe.close()
    except sqlite3.Error as exc:
        return exc
    return None


_COLUMNS: Final = {
    "tiles": ("zoom_level", "tile_column", "tile_row", "tile_data"),
    "metadata": ("name", "value"),
}
"""The columns the store is read by, per table (spec 1.3)."""


def _not_mbtiles(db: sqlite3.Connection, tables: set[str]) -> str | None:
    """Why the database ``db`` holding ``tables`` is no MBTiles store, or None: a table missing,
    a table without the columns it is read by, or a zoom_level that is no zoom. Cheap, once a
    read of the file: the columns from ``PRAGMA table_info``, the zooms only the smallest and
    the largest (each one step of the spec's index: NULL sorts first, text and blobs last)."""
    missing = sorted({"metadata", "tiles"} - tables)
    if missing:
        return f"missing tables {missing}"
    for table, wanted in _COLUMNS.items():
        has = [str(r[1]) for r in db.execute(f"PRAGMA table_info({table})")]
        lacks = [c for c in wanted if c not in {h.lower() for h in has}]
        if lacks:
            return f"its {table} table lacks the columns {lacks}; it has {has}"
    for order in ("ASC", "DESC"):
        row = db.execute(f"SELECT zoom_level FROM tiles ORDER BY zoom_level {order} LIMIT 1")
        found = row.fetchone()
        if found is not None and not _is_zoom(found[0]):
            return holds("zoom_level", found[0])
    return None


def stored_zooms(db: BoundedConnection) -> list[int] | str:
    """The zooms of the tiles table, smallest first, or why one is no zoom (the check at open
    sees the smallest and the largest only): one seek of the spec's index per zoom, so a store
    of any size answers in milliseconds, all within ``OPEN_S`` (QueryTimeoutError otherwise:
    a view that never ends)."""
    found: list[int] = []
    query = "SELECT min(zoom_level) FROM tiles WHERE zoom_level > ?"
    with db.within(OPEN_S, "listing its zooms"):
        row = db.execute("SELECT min(zoom_level) FROM tiles").fetchone()
        while row is not None and row[0] is not None:
            if not _is_zoom(row[0]):
                return holds("zoom_level", row[0])
            zoom = whole_number(row[0])
            if zoom is not None and zoom not in found:  # 15 and 15.0 are one zoom
                found.append(zoom)
            row = db.execute(query, (row[0],)).fetchone()
    return found


def _is_zoom(value: object) -> bool:
    whole = whole_number(value)
    return whole is not None and whole >= 0


def refusal(path: Path, wrong: str) -> InvalidInputError:
    """The refusal of the store at ``path`` as no MBTiles file, for the reason ``wrong``."""
    return InvalidInputError("mbtiles", f"{path}: not an MBTiles file ({wrong})")


def stored_xyz(
    path: Path, zoom: int, cell: tuple[object, object], from_north: bool
) -> tuple[int, int]:
    """XYZ (x, y) of the stored (``tile_column``, ``tile_row``) ``cell`` at ``zoom`` of the
    store at ``path``, its row counted as the store counts them
    (:func:`~c3_matcher.tilestore.mbtiles_form.stored_row`); a value that is no integer is
    InvalidInputError naming the store."""
    col, row = cell
    x, stored = whole_number(col), whole_number(row)
    if x is None:
        raise refusal(path, holds("tile_column", col))
    if stored is None:
        raise refusal(path, holds("tile_row", row))
    return x, stored_row(zoom, stored, from_north)


def holds(column: str, value: object) -> str:
    """What a ``column`` of the tiles table holding ``value`` (none of its kind) is said as."""
    shown = "NULL" if value is None else repr(value)
    shown = shown if len(shown) <= 40 else shown[:37] + "..."
    expected = "a zoom is an integer >= 0" if column == "zoom_level" else "it is an integer"
    return f"its tiles table holds a {column} of {shown}: {expected}"
