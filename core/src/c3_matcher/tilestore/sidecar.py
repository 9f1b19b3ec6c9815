"""The sidecar database ``<store>.features.sqlite`` of stored map features (the format:
:mod:`c3_matcher.tilestore.features`): read-only and never waiting on a lock in flight, the
single writer on the ground. What it raises: :mod:`c3_matcher.tilestore.sidecar_errors`."""

from __future__ import annotations

import contextlib
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from c3_matcher.errors import describe
from c3_matcher.tilestore import bounded
from c3_matcher.tilestore.bounded import BoundedConnection
from c3_matcher.tilestore.files import connect_read_only, open_failure, wal_blocked
from c3_matcher.tilestore.sidecar_errors import (
    FeatureStoreUnavailableError,
    SidecarDamagedError,
    StoredFeaturesCorruptError,
)
from c3_matcher.tilestore.sidecar_file import LEAVE_WAL_S, leave_wal, schema_mismatch, sqlite_code
from c3_matcher.tilestore.windows import FeatureSet, WindowFeatures, decode_row, row_checksum

WindowKey = tuple[int, int, int]  # (zoom, gx, gy)

FEATURES_SUFFIX = ".features.sqlite"
DEFAULT_RETRY_S = 30.0  # a locked or unreadable sidecar is tried again after this long
PAGE_BYTES = 65536  # SQLite page size of a new sidecar (a row is about a megabyte)
_DAMAGE = (sqlite3.SQLITE_NOTADB, sqlite3.SQLITE_CORRUPT)  # SQLite's "the file is damaged"
_ROW_COLUMNS = "window_digest, n, keypoints, scores, descriptors, checksum"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS window_sets (
    set_id TEXT PRIMARY KEY, extractor_sha256 TEXT NOT NULL, provider TEXT NOT NULL,
    multiple INTEGER NOT NULL, photometric TEXT NOT NULL, border_erode_px INTEGER NOT NULL,
    window_px INTEGER NOT NULL, stride_px INTEGER NOT NULL, descriptor_dim INTEGER NOT NULL,
    strategy TEXT NOT NULL, complete INTEGER NOT NULL DEFAULT 0,
    windows INTEGER NOT NULL DEFAULT 0, descriptor_dtype TEXT NOT NULL, created TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS window_features (
    set_id TEXT NOT NULL, zoom INTEGER NOT NULL, gx INTEGER NOT NULL, gy INTEGER NOT NULL,
    window_digest TEXT NOT NULL, n INTEGER NOT NULL, keypoints BLOB NOT NULL,
    scores BLOB NOT NULL, descriptors BLOB NOT NULL, checksum TEXT NOT NULL,
    PRIMARY KEY (set_id, zoom, gx, gy)) WITHOUT ROWID;
"""

_SET_COLUMNS = (
    "set_id, extractor_sha256, provider, multiple, photometric, border_erode_px, window_px, "
    "stride_px, descriptor_dim, strategy, complete, windows, descriptor_dtype"
)

T = TypeVar("T")


def sidecar_path(store_path: str | Path) -> Path:
    """``<store>.features.sqlite`` beside the tile store."""
    p = Path(store_path)
    return p.with_name(p.name + FEATURES_SUFFIX)


class MapFeatureStore:
    """The sidecar database: read-only and never waiting on a lock by default (the flight);
    ``writable=True`` for the ground command (the single writer)."""

    def __init__(
        self,
        path: str | Path,
        *,
        writable: bool = False,
        retry_s: float = DEFAULT_RETRY_S,
        clock: Callable[[], float] = time.monotonic,
        leave_wal_s: float = LEAVE_WAL_S,
    ) -> None:
        self.path = Path(path)
        self._leave_wal_s = float(leave_wal_s)
        self._writable = writable
        self._retry_s = float(retry_s)
        self._clock = clock
        self._sets: dict[str, FeatureSet | None] = {}
        self._held: tuple[str, ...] | None = None  # the set ids stored, once read
        self._down_until: float | None = None  # unavailable: nothing served before this time
        self._reported = False  # this outage was already raised
        self._refused: set[tuple[str, int, int, int]] = set()
        self._reading = threading.Lock()
        self._db = _open_writable(self.path) if writable else _open_read_only(self.path)

    # -- reading ------------------------------------------------------------------------
    def _read(self, query: Callable[[], T]) -> T | None:
        """``query`` unless the store is in an outage (None); the first failure of an outage
        raises FeatureStoreUnavailableError, later ones within it return None. The writer has
        no outages: its errors are raised (damage as SidecarDamagedError)."""
        if self._writable:
            with _damage_refused(self.path, self._db):
                return query()
        now = self._clock()
        if self._down_until is not None and now < self._down_until:
            return None
        try:
            with self._reading, self._db.within(bounded.READ_S, "the read"):  # one at a time
                result = query()
        except sqlite3.Error as exc:
            self._down_until = now + self._retry_s
            self._sets.clear()
            self._held = None
            if self._reported:
                return None
            self._reported = True
            why, fix = _unreadable(self.path, exc)
            raise FeatureStoreUnavailableError(
                self.path, why, fix=fix, retry_s=self._retry_s
            ) from exc
        self._down_until, self._reported = None, False
        return result

    def feature_set(self, set_id: str) -> FeatureSet | None:
        if set_id not in self._sets:
            row = self._read(
                lambda: self._db.execute(
                    f"SELECT {_SET_COLUMNS} FROM window_sets WHERE set_id=?", (set_id,)
                ).fetchone()
            )
            if row is None and self._down_until is not None:
                return None  # unavailable: not remembered as absent
            try:
                self._sets[set_id] = None if row is None else _set_of(self.path, row)
            except SidecarDamagedError:
                if not self._writable:  # the flight: said once, then never served
                    self._sets[set_id] = None
                raise
        return self._sets[set_id]

    def set_ids(self) -> tuple[str, ...] | None:
        """The id of every set stored, sorted, read once (again after an outage or a write);
        None in an outage (nothing can be told then)."""
        if self._held is None:
            rows = self._read(
                lambda: self._db.execute("SELECT set_id FROM window_sets ORDER BY 1").fetchall()
            )
            if rows is None:
                return None
            self._held = tuple(str(row[0]) for row in rows)
        return self._held

    def feature_sets(self) -> list[FeatureSet]:
        """Every set stored; SidecarDamagedError naming the first malformed set row."""
        rows = self._read(
            lambda: self._db.execute(
                f"SELECT {_SET_COLUMNS} FROM window_sets ORDER BY 1"
            ).fetchall()
        )
        return [_set_of(self.path, r) for r in rows or ()]

    def window(self, fset: FeatureSet, zoom: int, gx: int, gy: int) -> WindowFeatures | None:
        """Grid window (gx, gy) of ``fset`` at ``zoom``, verified against its checksum and shapes;
        None when not stored (or in an outage). StoredFeaturesCorruptError the first time a
        corrupt row (or one whose database pages SQLite finds damaged) is read, None
        afterwards."""
        key = (fset.set_id, zoom, gx, gy)
        if key in self._refused:
            return None
        row = self._read(lambda: self._row(key))
        if row is None:
            return None
        try:
            if isinstance(row, sqlite3.DatabaseError):
                raise ValueError(f"unreadable ({' '.join(str(row).split())})")
            return decode_row(fset, key, row)
        except ValueError as exc:
            self._refused.add(key)
            raise StoredFeaturesCorruptError(
                f"{self.path}: window {zoom}/{gx}/{gy} of set {fset.set_id[:12]}...: {exc}; "
                "refused, extracting instead"
            ) from None

    def _row(self, key: tuple[str, int, int, int]) -> Sequence[Any] | sqlite3.DatabaseError | None:
        """The stored row of ``key``; SQLite's error when the pages holding it are damaged (that
        row's fault, not the store's: other rows are still served)."""
        try:
            row: Sequence[Any] | None = self._db.execute(
                f"SELECT {_ROW_COLUMNS} FROM window_features "
                "WHERE set_id=? AND zoom=? AND gx=? AND gy=?",
                key,
            ).fetchone()
        except sqlite3.DatabaseError as exc:
            if sqlite_code(exc) == sqlite3.SQLITE_CORRUPT:
                return exc
            raise
        return row

    def done_windows(self, set_id: str) -> dict[WindowKey, str]:
        """(zoom, gx, gy) -> window digest of every window stored in a set (as stored: see
        :meth:`checked_windows`); SidecarDamagedError for a key that is no integer."""
        with _damage_refused(self.path, self._db):
            return {
                self._window_key(set_id, z, x, y): str(d)
                for z, x, y, d in self._db.execute(
                    "SELECT zoom, gx, gy, window_digest FROM window_features WHERE set_id=?",
                    (set_id,),
                )
            }

    def _window_key(self, set_id: str, z: object, x: object, y: object) -> WindowKey:
        """A ``window_features`` row's (zoom, gx, gy) as stored; SidecarDamagedError naming the
        row when one is no integer (SQLite keeps any value in an INTEGER column)."""
        if isinstance(z, int) and isinstance(x, int) and isinstance(y, int):
            return z, x, y
        key = "/".join(repr(v)[:20] for v in (z, x, y))
        raise SidecarDamagedError(
            self.path,
            f"damaged (window_features row of set {set_id[:12]}...: key {key} is not "
            "zoom/gx/gy integers)",
        )

    def checked_windows(
        self, fset: FeatureSet
    ) -> tuple[dict[WindowKey, str], dict[WindowKey, str]]:
        """Every window stored in ``fset``, each row read and verified as :meth:`window` verifies
        it: (zoom, gx, gy) -> window digest of the intact ones, and -> why of the damaged ones
        (checksum mismatch, undecodable). SidecarDamagedError when SQLite finds the database
        itself damaged."""
        intact: dict[WindowKey, str] = {}
        damaged: dict[WindowKey, str] = {}
        with _damage_refused(self.path, self._db):
            for z, x, y, *row in self._db.execute(
                f"SELECT zoom, gx, gy, {_ROW_COLUMNS} FROM window_features WHERE set_id=?",
                (fset.set_id,),
            ):
                key = self._window_key(fset.set_id, z, x, y)
                try:
                    intact[key] = decode_row(fset, (fset.set_id, *key), row).window_digest
                except ValueError as exc:
                    damaged[key] = str(exc)
        return intact, damaged

    # -- writing (ground) ---------------------------------------------------------------
    def ensure_set(self, fset: FeatureSet) -> None:
        self._write(
            f"INSERT OR IGNORE INTO window_sets ({_SET_COLUMNS}, created) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 0, 0, ?, ?)",
            [
                (
                    fset.set_id,
                    fset.extractor_sha256,
                    fset.provider,
                    fset.multiple,
                    fset.photometric,
                    fset.border_erode_px,
                    fset.window_px,
                    fset.stride_px,
                    fset.descriptor_dim,
                    fset.strategy,
                    fset.descriptor_dtype,
                    time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                )
            ],
        )
        self._sets.pop(fset.set_id, None)
        self._held = None

    def put_windows(
        self, set_id: str, rows: Iterable[tuple[int, int, int, WindowFeatures]]
    ) -> None:
        self._write(
            "INSERT OR REPLACE INTO window_features VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (
                    set_id,
                    z,
                    gx,
                    gy,
                    w.window_digest,
                    len(w.scores),
                    *blobs,
                    row_checksum((set_id, z, gx, gy), w.window_digest, len(w.scores), blobs),
                )
                for z, gx, gy, w in rows
                for blobs in (w.blobs(),)
            ],
        )

    def drop_windows(self, set_id: str, keys: Iterable[WindowKey]) -> None:
        """Delete the windows (zoom, gx, gy) ``keys`` of a set."""
        self._write(
            "DELETE FROM window_features WHERE set_id=? AND zoom=? AND gx=? AND gy=?",
            [(set_id, *k) for k in keys],
        )

    def mark(self, set_id: str, *, complete: bool, windows: int) -> None:
        self._write(
            "UPDATE window_sets SET complete=?, windows=? WHERE set_id=?",
            [(int(complete), int(windows), set_id)],
        )
        self._sets.pop(set_id, None)

    def _write(self, sql: str, rows: Sequence[Sequence[Any]]) -> None:
        """``sql`` once per row of parameters, committed; SQLite finding the database damaged
        raised as SidecarDamagedError."""
        with _damage_refused(self.path, self._db):
            self._db.executemany(sql, rows)
            self._db.commit()

    def close(self) -> None:
        """Close; the writer first leaves WAL (:func:`leave_wal`: tried for ``leave_wal_s``
        while a reader holds it), so the sidecar is one self-contained file that a reader on
        read-only media can open; SidecarInUseError (closed all the same) when it cannot be."""
        try:
            if self._writable:
                leave_wal(self._db, self.path, self._leave_wal_s)
        finally:
            self._db.close()

    def __enter__(self) -> MapFeatureStore:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is not None:  # the error in flight is the one said: one try, no wait
            self._leave_wal_s = 0.0
        with contextlib.suppress(*(() if exc_type is None else (sqlite3.Error,))):
            self.close()


def _open_read_only(path: Path) -> BoundedConnection:
    """The flight's read-only connection, for every thread in turn (``_read``), busy timeout 0:
    a lock held elsewhere fails at once, the frame never waits; never memory-mapped, so a
    sidecar rewritten in place is an outage, not a SIGBUS. FeatureStoreUnavailableError saying
    why a sidecar cannot be opened (its permission, a directory), its cause SQLite's."""
    try:
        return connect_read_only(path, timeout=0)
    except sqlite3.Error as exc:
        why = open_failure(path, "a features sidecar") or f"cannot open ({exc})"
        raise FeatureStoreUnavailableError(path, why) from exc


def _open_writable(path: Path) -> BoundedConnection:
    """The writer's connection to the sidecar ``path`` (created when absent), its tables read
    once and every set row parsed; SidecarDamagedError when the file is not an SQLite database
    or a damaged one, its tables another version's (never migrated: an old set's rows may not
    be what its id now means) or a set row malformed (a lock held elsewhere is waited for)."""
    db = sqlite3.connect(str(path), timeout=LEAVE_WAL_S, factory=BoundedConnection)
    try:
        with _damage_refused(path, db):
            db.execute(f"PRAGMA page_size={PAGE_BYTES}")  # a new file: fewer pages a row
            db.executescript(_SCHEMA)
            if (mismatch := schema_mismatch(db, _SCHEMA)) is not None:
                raise SidecarDamagedError(path, mismatch)
            with _damage_refused(path, db, bounded.OPEN_S):  # sets that never end: damaged
                for row in db.execute(f"SELECT {_SET_COLUMNS} FROM window_sets"):
                    _set_of(path, row)  # `features info` says which
            db.commit()
            db.execute("PRAGMA journal_mode=WAL")  # once readable: a damaged file is left as is
    except BaseException:  # damaged, a malformed set row, another schema: left as is (no WAL)
        db.close()
        raise
    return db


def _unreadable(path: Path, exc: sqlite3.Error) -> tuple[str, str]:
    """Why the sidecar ``path`` cannot be read (``exc``, SQLite's error), in words, and what
    makes it readable ("" when nothing here can tell)."""
    if (blocked := wal_blocked(path, exc)) is None:
        return describe(exc), ""
    return (
        "cannot be read here: an older c3-matcher (or a build that a reader held open) left it "
        f"{blocked}",
        "`c3-matcher features build` of its store, where it can be written, makes it one file "
        "that read-only media serve, keeping its features",
    )


@contextlib.contextmanager
def _damage_refused(
    path: Path, db: BoundedConnection, seconds: float = bounded.UNBOUNDED
) -> Iterator[None]:
    """The statements of ``db`` on the database ``path`` within ``seconds`` (a signal stops
    them); SQLite's errors saying it is damaged, or that it did not answer in time (a view
    that never ends), raised as SidecarDamagedError."""
    try:
        with db.within(seconds, "reading its tables"):
            yield
    except sqlite3.DatabaseError as exc:
        if sqlite_code(exc) in _DAMAGE or isinstance(exc, bounded.QueryTimeoutError):
            raise SidecarDamagedError(path, exc) from exc
        raise


def _set_of(path: Path, row: Sequence[Any]) -> FeatureSet:
    """A ``window_sets`` row of the sidecar ``path``; SidecarDamagedError naming the row and
    its first malformed value."""
    try:
        return FeatureSet.of_row(row)
    except ValueError as exc:
        raise SidecarDamagedError(
            path, f"damaged (window_sets row {str(row[0])[:12]}...: {exc})"
        ) from None
