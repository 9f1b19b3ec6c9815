"""MBTiles (the SQLite tile format GDAL and QGIS write, spec 1.3): read and write.

Schema (spec 1.3)::

    CREATE TABLE metadata (name TEXT, value TEXT);
    CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER,
                        tile_data BLOB);
    CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row);

Tiles are 256-px web-mercator tiles; ``tile_row`` is TMS (row 0 at the south), so XYZ ``y`` is
``2**zoom - 1 - tile_row``, or ``tile_row`` itself where the metadata ``scheme`` is ``xyz`` (as
some tools write: ``mbtiles_form.stored_row``). Metadata holds the spec's ``name``, ``format``,
``bounds``, ``center``, ``minzoom``, ``maxzoom``, ``type`` plus, for stores built by ``c3-matcher
tiles build``, ``c3_source`` (the GeoTIFF), ``c3_georeference`` (how its grid was converted to
WGS84: the JSON of the ground tools' ``tilestore.projection.Projection``) and ``c3_source_gsd_m``.

Opening checks, once, that the file is an SQLite database with these two tables, each with the
columns it is read by (``PRAGMA table_info``), that its smallest and largest zoom_level are
zooms (integers >= 0), its ``scheme`` one it reads and one tile's header 256 px square
(``mbtiles_form``); a file that is not is ``InvalidInputError`` naming it and what is wrong.

Reading opens the database read-only and never memory-maps it (``files.connect_read_only``):
pages are ``read()`` into SQLite's cache, so a file emptied or cut short while open is an
outage (below), never a SIGBUS. A ``tiles`` view may never end: the read at open ends within
``bounded.OPEN_S`` (refused), a tile's within ``READ_S`` (its error); a signal stops any.
Each tile blob reaches Python as one ``bytes`` (the sqlite3 module's only way; a tile_data of
another type, TEXT or a number, is its tile's error) and handles expose it as a ``memoryview``.
A database error while reading a tile (a corrupt page) is raised as that tile's error, never a
crash of the caller, and the thread's connection is made afresh for its next read. Which tiles
a range of columns and rows holds is one query of the tile index, no tile read (``stored_in``).

Threads: each thread gets its own read-only connection (SQLite objects may not cross threads),
so a store opened on one thread serves another; the connections of threads that have ended are
closed when the next one is made, and all of them by ``close()``, after which every read raises
``TileStoreUnusableError`` saying the store is closed. A store-wide failure (a fresh connection
reads neither its metadata nor a tile other than the one that failed: locked by another process,
truncated or emptied in place, unreadable; one damaged row is its tile's error) is reported
ONCE per outage as an ERROR log ``c3.tilestore.unusable`` naming the store (forwarded to the
FDR as ``log.error``), then raised at once as each tile's ``TileStoreUnusableError``; every
``retry_s`` seconds one read tries the store again (on fresh connections) and, when it answers,
tiles are served again. A frame never waits on a lock for more than ``LOCK_WAIT_S`` (SQLite's
busy timeout, long enough to ride through another process's commit).

A map changed under a running store is followed: the path is looked at (``os.stat``, its
``mbtiles_file.FileIdentity``) at most once every ``check_s`` seconds (``CHECK_S``, 1 s: a
``stat`` costs a tenth of a tile read) and at once after a read fails. When it names another
file (a rename over it: ``mv``, ``os.replace``) or the file was rewritten in place, the file is
read again as at open (metadata, whether tiles carry digests), said once per change (WARNING
``c3.tilestore.changed`` naming the store), and each thread's next read is on a fresh
connection to it: within ``check_s`` of a change every thread serves the new map (a read that
fails meanwhile is read again at once on the new file). A thread's old connection is closed at
its next read or by ``close()``. A changed file that cannot be read as a store (emptied,
half-written) is read as it stands, an outage as above, and looked at again until it can; a
file deleted keeps serving threads connected before and is an outage to the others. Not seen:
a rewrite in place keeping the inode, the size and the mtime (within the file system's
timestamp tick, or set back), whose old pages SQLite may serve from its cache.

Integrity: a store built by ``c3-matcher tiles build`` holds a ``c3_tile_digest`` table (sha256
of each tile blob). When present, every blob read is verified against it; a mismatch raises
``TileDigestError`` naming the tile, so the pipeline drops that candidate with an FDR record.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Final

from c3_matcher.errors import InvalidInputError, describe
from c3_matcher.tilestore.base import TileStoreBase
from c3_matcher.tilestore.bounded import READ_S, UNBOUNDED, BoundedConnection
from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path
from c3_matcher.tilestore.files import connect_read_only, open_error, open_failure
from c3_matcher.tilestore.mbtiles_file import (
    CHECK_S,
    LOCK_WAIT_S,
    FollowedFile,
    StoreFile,
    TileDigestError,
    file_identity,
    probe_failure,
    read_store_file,
    refusal,
    stored_xyz,
    stored_zooms,
    verified_tile,
)
from c3_matcher.tilestore.mbtiles_form import stored_row
from c3_matcher.tilestore.sidecar import DEFAULT_RETRY_S, FeatureStoreUnavailableError

__all__ = ["MBTilesStore", "TileDigestError", "TileStoreUnusableError"]


class TileStoreUnusableError(InvalidInputError):
    """The whole store no longer answers (not one tile's problem)."""


RETRY_S = 5.0  # an unusable store is tried again after this long


class MBTilesStore(TileStoreBase):
    """A read-only MBTiles store (see the module docstring). ``close()`` when done."""

    def __init__(
        self,
        path: str | Path,
        *,
        retry_s: float = RETRY_S,
        check_s: float = CHECK_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path: Final = Path(path)
        self.name: Final = self.path.name
        why = open_failure(self.path, "an MBTiles file")
        if why is not None:  # a directory, a permission, not "unable to open database file"
            where = f"no such file: {self.path}" if why == "no such file" else f"{self.path}: {why}"
            raise InvalidInputError("mbtiles", where)
        self._retry_s = float(retry_s)
        self._clock = clock
        self._retry_at = 0.0
        self._local = threading.local()
        self._connections: dict[threading.Thread, BoundedConnection] = {}
        self._conn_lock = threading.Lock()
        self._closed = False
        self._pid = os.getpid()  # a fork's child closes its copy without touching a connection
        self._inherited: tuple[object, ...] = ()  # what such a child left unclosed
        self._unusable: str | None = None
        self._features: MapFeatureStore | None = None
        self._features_retry_at: float | None = None  # an unopenable sidecar: next try then
        try:  # a damaged page (metadata's included) is said as such
            found = read_store_file(self.path, file_identity(self.path), timeout=LOCK_WAIT_S)
        except sqlite3.DatabaseError as exc:
            why = open_error(self.path, exc, "an MBTiles file")
            raise InvalidInputError("mbtiles", f"{self.path}: {why}") from exc
        if isinstance(found, str):
            raise refusal(self.path, found)
        self._followed = FollowedFile(self.path, found, check_s=check_s, clock=clock)

    @property
    def tile_size(self) -> tuple[int, int] | None:
        """(width, height) of the tile whose header was read at open, None when none told it."""
        return self._followed.current.tile_size

    @property
    def has_digests(self) -> bool:
        """Whether the store carries per-tile sha256 digests (verified on every read)."""
        return self._followed.current.has_digests

    @property
    def _db(self) -> BoundedConnection:
        """This thread's read-only connection to the store file as last read (see
        :meth:`_connection`), the file looked at first when ``check_s`` has passed."""
        self._follow_in_time()
        return self._connection(self._followed.current)

    def _connection(self, file: StoreFile) -> BoundedConnection:
        """This thread's read-only connection made since ``file`` was read (when it was not,
        the thread's older one and those of ended threads are closed); a closed store refuses
        (TileStoreUnusableError)."""
        held: tuple[StoreFile, BoundedConnection] | None = getattr(self._local, "held", None)
        if held is not None and held[0] is file:
            return held[1]
        with self._conn_lock:
            if self._closed:
                raise TileStoreUnusableError(
                    str(self.path), "the store is closed (close() was called): open it again"
                )
            gone = [t for t in self._connections if t is threading.current_thread()]
            for ended in gone + [t for t in self._connections if not t.is_alive()]:
                self._connections.pop(ended).close()
            # used only by this thread; any thread may close it
            db = connect_read_only(self.path, timeout=LOCK_WAIT_S)
            self._connections[threading.current_thread()] = db
        self._local.held = (file, db)
        return db

    def _follow_in_time(self) -> None:
        """Look at the store file (:meth:`_follow_file`) when ``check_s`` has passed since the
        last look: a clock read per tile read, a ``stat`` per ``check_s``."""
        if self._followed.due():
            self._follow_file()

    def _follow_file(self) -> bool:
        """Read the store file again when it changed (``FollowedFile.look``), so that every
        thread's next read is on a fresh connection to it; True when it was read as a store,
        said once (WARNING ``c3.tilestore.changed``). A closed store is left as it is."""
        if self._closed:
            return False  # (a fork's child may not wait on a lock a parent's thread held)
        if (found := self._followed.look()) is None:
            return False
        self._retry_at = 0.0  # it answered: an outage is tried again at once
        from c3_matcher.logs import log_event

        log_event(
            "WARNING",
            "c3.tilestore.changed",
            f"tile store {self.path} is another file now (replaced or rewritten): every"
            " thread serves its tiles from its next read",
            store=str(self.path),
            has_digests=found.has_digests,
        )
        return True

    def feature_store(self) -> MapFeatureStore | None:
        """The precomputed map features beside the store (``<store>.features.sqlite``), or None.
        A sidecar that cannot be opened (its permission) raises FeatureStoreUnavailableError
        once, then is None (extract) until it is tried again ``DEFAULT_RETRY_S`` later: said
        once an outage, as a locked one is, not by every candidate of every frame."""
        if self._features is not None:
            return self._features
        side = sidecar_path(self.path)
        if self._closed or not side.is_file():
            return None  # closed: its tiles' reads say so
        retry_at = self._features_retry_at
        if retry_at is not None and self._clock() < retry_at:
            return None
        try:
            self._features = MapFeatureStore(side)
        except FeatureStoreUnavailableError:
            self._features_retry_at = self._clock() + DEFAULT_RETRY_S
            if retry_at is None:
                raise  # the outage's first word; later failed tries are silent
            return None
        self._features_retry_at = None
        return self._features

    @property
    def metadata(self) -> Mapping[str, str]:
        return dict(self._followed.current.metadata)

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None:
        """The encoded XYZ tile (zoom, x, y), or None when absent; a database error is raised
        as InvalidInputError naming the tile."""
        key = (zoom, x, y)
        what = f"{self.name} tile {zoom}/{x}/{y}"
        self._follow_in_time()
        if self._unusable is not None:
            if self._clock() < self._retry_at:
                raise TileStoreUnusableError(what, self._unusable)
            self._close_connections()  # try again, on fresh connections
        try:
            found = self._fetch(key)
        except sqlite3.Error as exc:
            found = self._fetch_again(key, exc, what)
        if self._unusable is not None:
            self._unusable = None
            from c3_matcher.logs import log_event

            log_event(
                "WARNING",
                "c3.tilestore.recovered",
                f"tile store {self.path} answers again; serving tiles",
                store=str(self.path),
            )
        return verified_tile(found, what)

    def _fetch(self, key: tuple[int, int, int]) -> tuple[object, object] | None:
        """The (blob, sha256 or None) row of the XYZ tile ``key``, read with the query of the
        store file as last read (its rows counted as it counts them), on this thread's
        connection made since."""
        file, (zoom, x, y) = self._followed.current, key
        row = stored_row(zoom, y, file.rows_from_north)
        with (db := self._connection(file)).within(READ_S, "the read"):
            found: tuple[object, object] | None = db.execute(file.query, (zoom, x, row)).fetchone()
        return found

    def _fetch_again(
        self, key: tuple[int, int, int], exc: sqlite3.Error, what: str
    ) -> tuple[object, object] | None:
        """After the read of ``key`` failed (``exc``): read it again when the file changed (the
        failed read was on the old one, or by its query: a digests table gone); else, or when
        that fails too, the tile's InvalidInputError, or the store's (:meth:`_check_store`)."""
        if self._follow_file():
            try:
                return self._fetch(key)
            except sqlite3.Error as again:
                exc = again
        self._check_store(exc, key)
        self._forget_connection()
        raise InvalidInputError(what, f"read failed: {exc}") from exc

    def _check_store(self, exc: BaseException, key: tuple[int, int, int]) -> None:
        """After tile ``key``'s read failed: if a fresh connection reads neither the store's
        metadata nor another tile, it is unusable: said once (ERROR log, in the FDR), then every
        later tile fails fast."""
        failed = (*key[:2], stored_row(key[0], key[2], self._followed.current.rows_from_north))
        probe_exc = probe_failure(self.path, timeout=LOCK_WAIT_S, failed=failed)
        if probe_exc is None:
            return  # the store answers: this was one tile's error
        reason = f"store unusable: {describe(exc)} (probe: {probe_exc})"
        self._retry_at = self._clock() + self._retry_s
        if self._unusable is None:
            self._unusable = reason
            from c3_matcher.logs import log_event

            log_event(
                "ERROR",
                "c3.tilestore.unusable",
                f"tile store {self.path} is unusable: {reason}",
                store=str(self.path),
                error=reason,
            )
        raise TileStoreUnusableError(self.name, reason) from exc

    def _forget_connection(self) -> None:
        """Close this thread's connection after a read error the store itself does not share:
        its next read opens a fresh one."""
        held: tuple[StoreFile, BoundedConnection] | None = getattr(self._local, "held", None)
        if held is None:
            return
        with self._conn_lock:
            self._connections.pop(threading.current_thread(), None)
        self._local.held = None
        held[1].close()

    def zooms(self) -> list[int]:
        """The zooms stored (:func:`stored_zooms`); a zoom_level that is no zoom, or a tiles
        table not listing them in time, is InvalidInputError naming the store."""
        try:
            found = stored_zooms(self._db)
        except sqlite3.Error as exc:
            raise InvalidInputError(str(self.path), f"listing its zooms failed: {exc}") from exc
        if isinstance(found, str):
            raise refusal(self.path, found)
        return found

    def tiles(self, zoom: int) -> Iterator[tuple[int, int]]:
        """XYZ (x, y) of every stored tile at ``zoom`` (unbounded in time: a signal stops it);
        a tile_column or tile_row that is no integer is InvalidInputError naming the store."""
        self._follow_in_time()
        file = self._followed.current
        order = "2, 1" if file.rows_from_north else "2 DESC, 1"  # north first, as XYZ rows run
        query = f"SELECT tile_column, tile_row FROM tiles WHERE zoom_level=? ORDER BY {order}"
        with (db := self._connection(file)).within(UNBOUNDED, "listing its tiles"):
            for col, row in db.execute(query, (zoom,)):
                yield stored_xyz(self.path, zoom, (col, row), file.rows_from_north)

    def stored_in(
        self, zoom: int, columns: tuple[int, int], rows: tuple[int, int]
    ) -> list[tuple[int, int]]:
        """XYZ (x, y) of the tiles stored at ``zoom`` with x in ``columns`` and y in ``rows``
        (first, last), found in the tile index by one query within ``READ_S``: no tile is read,
        so a damaged or empty one is listed too (:meth:`tile_bytes` says what it holds). A
        database error is InvalidInputError naming the store."""
        query = (
            "SELECT tile_column, tile_row FROM tiles WHERE zoom_level=?"
            " AND tile_column BETWEEN ? AND ? AND tile_row BETWEEN ? AND ?"
        )
        self._follow_in_time()
        north = (file := self._followed.current).rows_from_north
        ends = sorted(stored_row(zoom, y, north) for y in rows)
        try:
            with (db := self._connection(file)).within(READ_S, "the listing"):
                found = db.execute(query, (zoom, *columns, *ends)).fetchall()
        except sqlite3.Error as exc:
            raise InvalidInputError(str(self.path), f"listing its tiles failed: {exc}") from exc
        return [stored_xyz(self.path, zoom, cell, north) for cell in found]

    def close(self) -> None:
        """Close every connection (the sidecar's too); later reads raise
        TileStoreUnusableError saying the store is closed. Idempotent. In a process forked from
        the one that opened it, at once (``_let_go_inherited``)."""
        if self._pid != os.getpid():
            self._let_go_inherited()
            return
        with self._conn_lock:
            self._closed = True
        if self._features is not None:
            self._features.close()
            self._features = None
        self._close_connections()

    def _close_connections(self) -> None:
        with self._conn_lock:
            for db in self._connections.values():
                db.close()
            self._connections.clear()
        self._local = threading.local()

    def _let_go_inherited(self) -> None:
        """Closed, in a fork's child, waiting for nothing: a thread of the parent, absent here,
        may have held the connections' lock or been inside one of them (holding its SQLite
        mutex) when it forked, so none is closed; they are kept unused, freed with the store."""
        self._closed = True
        self._inherited = (*self._inherited, self._connections, self._features)
        self._connections, self._features, self._local = {}, None, threading.local()

    def __enter__(self) -> MBTilesStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"MBTilesStore({str(self.path)!r})"
