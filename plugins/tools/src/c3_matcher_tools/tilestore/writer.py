"""``MBTilesWriter``: create an MBTiles store (spec 1.3; the schema the flight read path,
``c3_matcher.tilestore.mbtiles.MBTilesStore``, reads)."""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from c3_matcher.atomic import refuse_unwritable, temporary_sibling
from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import special_kind
from c3_matcher.tilestore.files import open_failure

__all__ = ["DigestReport", "MBTilesWriter", "add_missing_digests"]

_SIDE_FILES = ("-journal", "-wal", "-shm")  # SQLite's files beside a database

# per-tile sha256: the flight read path verifies it and drops a tile that fails
_DIGEST_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS c3_tile_digest (zoom_level INTEGER, tile_column INTEGER,"
    " tile_row INTEGER, sha256 TEXT)",
    "CREATE UNIQUE INDEX IF NOT EXISTS c3_tile_digest_index ON c3_tile_digest (zoom_level,"
    " tile_column, tile_row)",
)
_SCHEMA = (
    "CREATE TABLE metadata (name TEXT, value TEXT)",
    "CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,"
    " tile_data BLOB)",
    "CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)",
    "CREATE UNIQUE INDEX name ON metadata (name)",
    *_DIGEST_SCHEMA,
)


@dataclass(frozen=True, slots=True)
class DigestReport:
    """What ``add_missing_digests`` did: tiles in the store, digests added, digests already
    there (kept as they were), and tiles whose data is NULL or 0 bytes (no digest: the flight
    read path takes such a row for no tile)."""

    path: Path
    tiles: int
    added: int
    kept: int
    empty: int = 0


def add_missing_digests(path: str | Path) -> DigestReport:
    """Record the sha256 of every tile of the MBTiles store at ``path`` that has none (a store
    made by another tool, or before digests existed). Tile bytes are not touched, and an
    existing digest is never replaced: a tile that no longer matches its digest stays detected;
    a digest row whose sha256 is NULL (another tool's unfinished table) is no digest and is
    replaced. A tile whose data is NULL or 0 bytes (a blank tile as some tools store it) gets
    none and is counted apart (``empty``); one whose data is not bytes (an INTEGER, a TEXT) is
    refused, naming it. One transaction, the digest table's creation included: on any error (a
    file that is not an MBTiles store among them) the store is left as it was."""
    path = Path(path)
    why = open_failure(path, "an MBTiles file")
    if why == "no such file":
        raise InvalidInputError("store", f"no such MBTiles file: {path}")
    if why is not None:  # a directory, a permission: said, not "unable to open database file"
        raise InvalidInputError("store", f"{path}: {why}")
    try:  # transactions are ours: DDL included
        db = sqlite3.connect(str(path), isolation_level=None)
    except sqlite3.Error as exc:
        raise InvalidInputError("store", f"{path}: cannot open ({exc})") from exc
    try:
        db.execute("BEGIN IMMEDIATE")
        try:
            report = _digest_missing(db, path)
        except BaseException:
            if db.in_transaction:  # SQLite may have rolled it back itself
                db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")
    except sqlite3.Error as exc:
        raise InvalidInputError("store", f"{path}: {exc}") from exc
    finally:
        db.close()
    return report


_UNDIGESTED_WHERE = (  # each tile without a digest: none, or a row whose sha256 is NULL
    " FROM tiles t WHERE NOT EXISTS (SELECT 1 FROM c3_tile_digest d"
    " WHERE d.zoom_level=t.zoom_level AND d.tile_column=t.tile_column"
    " AND d.tile_row=t.tile_row AND d.sha256 IS NOT NULL)"
)
_UNDIGESTED = (
    "SELECT t.zoom_level, t.tile_column, t.tile_row, t.tile_data"
    + _UNDIGESTED_WHERE
    + " ORDER BY t.zoom_level, t.tile_column, t.tile_row"
)
_NOT_BYTES = (  # the first undigested tile whose data is neither a BLOB nor NULL, and how many
    "SELECT t.zoom_level, t.tile_column, t.tile_row, typeof(t.tile_data), count(*) OVER ()"
    + _UNDIGESTED_WHERE
    + " AND typeof(t.tile_data) NOT IN ('blob', 'null')"
    " ORDER BY t.zoom_level, t.tile_column, t.tile_row LIMIT 1"
)


def _digest_missing(db: sqlite3.Connection, path: Path) -> DigestReport:
    """Inside the caller's transaction: add the missing digests of the MBTiles store open as
    ``db`` (see :func:`add_missing_digests`). Refuses a database without a ``tiles`` table,
    and a tile whose data is not bytes, before any change. The tiles are read and hashed one
    at a time: only their keys and digests are held, whatever the size of the store."""
    has_tiles = db.execute(
        "SELECT 1 FROM sqlite_master WHERE type IN ('table', 'view') AND name = 'tiles'"
    ).fetchone()
    if has_tiles is None:
        raise InvalidInputError("store", f"{path}: not an MBTiles store (no table 'tiles')")
    for statement in _DIGEST_SCHEMA:
        db.execute(statement)
    _refuse_not_bytes(db, path)
    digests: list[tuple[object, object, object, str]] = []
    undigested = 0
    for z, x, row, blob in db.execute(_UNDIGESTED):  # one tile's bytes held at a time
        undigested += 1
        if blob:  # NULL and 0 bytes are no tile: a digest would vouch for a blank
            digests.append((z, x, row, hashlib.sha256(blob).hexdigest()))
    db.execute("DELETE FROM c3_tile_digest WHERE sha256 IS NULL")
    db.executemany("INSERT INTO c3_tile_digest VALUES (?, ?, ?, ?)", digests)
    (tiles,) = db.execute("SELECT count(*) FROM tiles").fetchone()
    empty = undigested - len(digests)
    return DigestReport(path, int(tiles), len(digests), int(tiles) - undigested, empty)


def _refuse_not_bytes(db: sqlite3.Connection, path: Path) -> None:
    """Refuse a store one of whose undigested tiles holds data that is neither bytes (a BLOB)
    nor NULL, naming the first such tile, its type and how many there are (asked of SQLite by
    type: no tile's data is read): the flight read path cannot decode it, and a digest of it
    would vouch for it."""
    wrong = db.execute(_NOT_BYTES).fetchone()
    if wrong is not None:
        z, x, row, kind, count = wrong
        more = f" (and {count - 1} more tiles)" if count > 1 else ""
        raise InvalidInputError(
            "store",
            f"{path}: the tile at zoom_level {z}, tile_column {x}, tile_row {row} holds "
            f"{str(kind).upper()} data, not an encoded image (a BLOB){more}: no digest added",
        )


class MBTilesWriter:
    """Create a new MBTiles file atomically: it is written as a hidden sibling (named by
    :func:`c3_matcher.atomic.temporary_sibling`) and renamed onto ``path`` by :meth:`close`;
    :meth:`abort` (or leaving the ``with`` block on any exception, Ctrl-C included) removes it
    and its journal, and an existing ``path`` is untouched until the rename (refused unless
    ``overwrite``, also when another build put it there while this one ran; with
    ``overwrite``, refused when another build replaced it meanwhile; a ``path`` that is not a
    regular file, a directory, a device, a FIFO or a socket, is refused even then). A
    store that cannot be written (a full disk, a file-size limit) is an ``InvalidInputError``
    naming ``path``, and nothing is left."""

    def __init__(self, path: str | Path, *, overwrite: bool = False) -> None:
        self._path = Path(path)
        self._overwrite = overwrite
        _refuse_special(self._path)
        if self._path.exists() and not overwrite:
            raise InvalidInputError("mbtiles", f"{self._path} exists (use --force)")
        refuse_unwritable(self._path, field="mbtiles")
        self._found = _identity(self._path)  # what --force replaces: that file, or none
        self._path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temporary_sibling(self._path)
        self._db: sqlite3.Connection | None = None
        with self._writing():
            self._db = sqlite3.connect(str(self._tmp))
            for statement in _SCHEMA:
                self._db.execute(statement)

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """SQLite failing to write the store (``database or disk is full``, ``disk I/O
        error`` past a file-size limit) is said of the path, as a fault of where it is
        written, and the unfinished store is dropped; so is any other failure."""
        try:
            yield
        except sqlite3.OperationalError as exc:
            self.abort()
            raise InvalidInputError("mbtiles", f"{self._path}: cannot be written: {exc}") from exc
        except BaseException:
            self.abort()
            raise

    def _open(self) -> sqlite3.Connection:
        if self._db is None:
            raise InvalidInputError("mbtiles", f"{self._path}: the writer is closed")
        return self._db

    def put_tile(self, zoom: int, x: int, y: int, data: bytes) -> None:
        """Store XYZ tile (zoom, x, y) (converted to a TMS row) and its sha256."""
        row = (1 << zoom) - 1 - y
        db = self._open()
        with self._writing():
            db.execute(
                "INSERT OR REPLACE INTO tiles VALUES (?, ?, ?, ?)",
                (zoom, x, row, sqlite3.Binary(data)),
            )
            db.execute(
                "INSERT OR REPLACE INTO c3_tile_digest VALUES (?, ?, ?, ?)",
                (zoom, x, row, hashlib.sha256(data).hexdigest()),
            )

    def put_metadata(self, values: Mapping[str, object]) -> None:
        db = self._open()
        with self._writing():
            for key, value in values.items():
                text = value if isinstance(value, str) else json.dumps(value)
                db.execute("INSERT OR REPLACE INTO metadata VALUES (?, ?)", (key, text))

    def close(self) -> None:
        """Commit, compact and rename the store onto its path (the one moment it appears)."""
        db = self._open()
        with self._writing():
            db.commit()
            db.execute("VACUUM")
            db.close()
            self._db = None
            self._name()

    def _name(self) -> None:
        """Give the finished store its path. Without ``overwrite``, only while nothing else has
        it: a store another build put there meanwhile is kept (a hard link, which fails when the
        name exists, then the temporary name removed; a rename where the filesystem has no hard
        links)."""
        if self._overwrite:
            if _identity(self._path) != self._found:  # both builds would say they wrote it
                raise InvalidInputError(
                    "mbtiles",
                    f"{self._path} was replaced while this build ran (another build?); kept as "
                    "it is: build again to replace it",
                )
            os.replace(self._tmp, self._path)
            return
        try:
            os.link(self._tmp, self._path)
        except FileExistsError:
            raise InvalidInputError(
                "mbtiles",
                f"{self._path} appeared while this build ran (another build?); "
                "kept as it is: use --force to replace it",
            ) from None
        except OSError:  # no hard links here (FAT, some network filesystems)
            if self._path.exists():
                raise InvalidInputError("mbtiles", f"{self._path} exists (use --force)") from None
            os.replace(self._tmp, self._path)
            return
        self._tmp.unlink()

    def abort(self) -> None:
        """Drop the unfinished store: nothing is left at the path or beside it."""
        if self._db is not None:
            self._db.close()
            self._db = None
        for leftover in (self._tmp, *(Path(f"{self._tmp}{s}") for s in _SIDE_FILES)):
            leftover.unlink(missing_ok=True)

    def __enter__(self) -> MBTilesWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _identity(path: Path) -> tuple[int, int, int, int] | None:
    """Which file ``path`` is now (device, inode, size, modification time), None when none
    is: a file replaced or rewritten in place reads as another."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _refuse_special(path: Path) -> None:
    """Refuse a ``path`` that exists and is not a regular file (followed through a symbolic
    link): the rename that ends a build would replace it, a device node or a FIFO with it, by
    its name."""
    kind = special_kind(path)
    if kind is not None:
        raise InvalidInputError("mbtiles", f"{path} is {kind}, not a file: it is never replaced")
