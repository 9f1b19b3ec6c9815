"""Store files (an MBTiles store, a map-features sidecar): why one cannot be opened, in words a
user can act on, found before SQLite is asked: SQLite says "unable to open database file" for a
missing file, a directory and a permission problem alike, and for a file in WAL journal mode
whose ``-shm`` cannot be made beside it (said once SQLite failed: :func:`wal_blocked`); such a
file on read-only media is read as immutable (:func:`unchanging`). Each is opened, by SQLite too,
only when it is a regular file just before (:func:`~c3_matcher.regular_files.open_regular`): a
FIFO put at its path, which SQLite's open would wait on forever, is refused."""

from __future__ import annotations

import errno
import os
import sqlite3
from pathlib import Path

from c3_matcher.file_kinds import kind_of
from c3_matcher.regular_files import SpecialFileError, open_regular
from c3_matcher.tilestore.bounded import BoundedConnection, QueryTimeoutError
from c3_matcher.tilestore.sidecar_file import sqlite_code

__all__ = [
    "cannot_open",
    "connect_read_only",
    "on_read_only_media",
    "open_error",
    "open_failure",
    "read_only_uri",
    "set_aside",
    "unchanging",
    "wal_blocked",
]

_COMPANIONS = ("-wal", "-shm", "-journal")  # SQLite's files beside a database, by suffix
_WAL_VERSION = 2  # an SQLite header's bytes 18 and 19 (write and read version) in WAL mode


def open_failure(path: str | Path, kind: str) -> str | None:
    """Why ``path`` cannot be opened for reading as ``kind`` (e.g. ``"an MBTiles file"``):
    ``"no such file"``, ``"is a directory, not <kind>"`` (or a FIFO, a device, a
    socket), ``"cannot open (permission denied)"`` or ``"cannot open (<the system's
    words>)"``; None when it opens."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:  # a folder on the way without search permission, a loop of links
        return cannot_open(exc)
    special = kind_of(st.st_mode)
    if special is not None:  # a FIFO or a device: opening it could block
        return f"is {special}, not {kind}"
    try:
        os.close(open_regular(p))  # one put at the path since is not waited on either
    except SpecialFileError as exc:
        return f"is {exc.kind}, not {kind}"
    except OSError as exc:
        return cannot_open(exc)
    return None


def open_error(path: Path, exc: sqlite3.DatabaseError, kind: str) -> str:
    """What an SQLite error on opening the store file ``path`` (``kind``, e.g. ``"an MBTiles
    file"``) says about it: locked, not to be opened (SQLite's CANTOPEN: the file's
    permission, a read-only folder a journal needs), a damaged one (a page SQLite finds
    malformed), one whose tables do not answer in time (a view that never ends: the
    :class:`QueryTimeoutError`'s words) or not an SQLite database (a text file)."""
    if isinstance(exc, QueryTimeoutError):
        return f"{exc}: refused, its tables (or views) do not answer in time"
    if _locked(exc):
        return f"locked by another process: {exc}"
    code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
    if code == sqlite3.SQLITE_CANTOPEN:
        return open_failure(path, kind) or f"cannot open ({exc})"
    if code == sqlite3.SQLITE_CORRUPT:
        return f"damaged SQLite database: {exc}"
    return f"not an SQLite database: {exc}"


def _locked(exc: BaseException) -> bool:
    """Whether an SQLite error says another connection holds a lock."""
    text = str(exc).lower()
    return "locked" in text or "busy" in text


def read_only_uri(path: str | Path) -> str:
    """The SQLite URI that opens the database file ``path`` read-only (``uri=True``): the
    absolute path percent-encoded, so that a ``#``, ``?`` or ``%`` in a folder's name is part of
    the name, not a fragment, a query or an escape (which would open another file, or drop
    ``mode=ro``); ``immutable=1`` too for a file that is :func:`unchanging`."""
    p = Path(path).resolve()
    return f"{p.as_uri()}?mode=ro{'&immutable=1' if unchanging(p) else ''}"


def connect_read_only(path: str | Path, *, timeout: float) -> BoundedConnection:
    """A read-only connection to the store file ``path`` (:func:`read_only_uri`), usable from
    any thread, waiting at most ``timeout`` seconds on a lock, its pages read with ``read()``,
    never memory-mapped (``PRAGMA mmap_size=0``, whatever SQLite's build default): a file cut
    short or rewritten in place while open (``truncate``, ``cp``) is an SQLite error at worst,
    where a mapped page past its new end would kill the process (SIGBUS). Its statements are
    bounded in :meth:`~c3_matcher.tilestore.bounded.BoundedConnection.within`.
    Raises SQLite's error when the file cannot be opened, and an OperationalError saying what
    it is when it is no regular file (a FIFO, which SQLite's open would wait on forever)."""
    _refuse_special(path)
    db = sqlite3.connect(
        read_only_uri(path),
        uri=True,
        timeout=timeout,
        check_same_thread=False,
        factory=BoundedConnection,
    )
    try:
        db.execute("PRAGMA mmap_size=0")
    except BaseException:
        db.close()
        raise
    return db


def _refuse_special(path: str | Path) -> None:
    """OperationalError (SQLite's words, then what it is) when ``path`` is no regular file now;
    any other failure to open it is left to SQLite to say."""
    try:
        os.close(open_regular(path))
    except SpecialFileError as exc:
        raise sqlite3.OperationalError(f"unable to open database file: {path}: {exc}") from None
    except OSError:
        return


def unchanging(path: Path) -> bool:
    """Whether the database ``path`` is read as an immutable file (SQLite then takes no lock
    and makes no ``-shm``): it is in WAL journal mode (an older c3-matcher left its sidecars so,
    other tools their MBTiles stores), no SQLite companion lies beside it (no connection has it
    open, no page waits in a ``-wal``) and its file system is mounted read-only. SQLite could
    not read it otherwise (a reader of a WAL file needs a ``-shm`` beside it, which cannot be
    made there), and nothing can write it while it is mounted so."""
    return (
        _in_wal_mode(path)
        and not any(_beside(path, s) for s in _COMPANIONS)
        and on_read_only_media(path)
    )


def on_read_only_media(path: Path) -> bool:
    """Whether the file system holding ``path`` is mounted read-only (``ST_RDONLY``)."""
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def wal_blocked(path: Path, exc: BaseException) -> str | None:
    """Why SQLite could not open the database ``path`` (``exc``, its error: CANTOPEN, or
    READONLY when the ``-shm`` cannot be written) when it is in WAL journal mode and no ``-shm``
    lies beside it: a reader needs one, and none could be made there (a read-only folder or
    medium); None when that is not so."""
    if sqlite_code(exc) not in (sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_READONLY):
        return None
    if not _in_wal_mode(path) or _beside(path, "-shm"):
        return None
    wal = Path(f"{path}-wal")
    pages = f"; its latest pages are only in {wal.name}" if _size(wal) else ""
    return (
        f"in WAL journal mode, which needs a {path.name}-shm file beside it, and none can be "
        f"made in its folder{pages}"
    )


def _in_wal_mode(path: Path) -> bool:
    """Whether the SQLite file ``path``'s header says WAL journal mode (False when it is no
    regular file or cannot be read; a FIFO is not waited on)."""
    try:
        fd = open_regular(path)
    except OSError:
        return False
    try:
        header = os.read(fd, 20)
    except OSError:
        return False
    finally:
        os.close(fd)
    return len(header) == 20 and header[18] == header[19] == _WAL_VERSION


def _beside(path: Path, suffix: str) -> bool:
    """Whether the SQLite companion ``<path><suffix>`` lies beside ``path`` (none can where its
    name would be too long; one that cannot be looked for is taken as there)."""
    try:
        return Path(f"{path}{suffix}").exists()
    except OSError as exc:
        return exc.errno != errno.ENAMETOOLONG


def _size(path: Path) -> int:
    """The size of the file ``path`` in bytes; 0 when there is none."""
    try:
        return path.stat().st_size
    except OSError:
        return 0


def cannot_open(exc: OSError) -> str:
    """``"cannot open (<why>)"`` for an OSError: ``permission denied`` for EACCES / EPERM."""
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "cannot open (permission denied)"
    return f"cannot open ({(exc.strerror or str(exc)).lower()})"


def set_aside(path: str | Path) -> Path:
    """Rename the sidecar ``path`` and its SQLite companions (``-wal``, ``-shm``, ``-journal``,
    whose pages would otherwise be replayed into a new file) to the first free
    ``<name>.damaged[.N]``, which is returned; nothing is deleted."""
    p = Path(path)
    names = ("", *_COMPANIONS)
    aside, n = p.with_name(f"{p.name}.damaged"), 0
    while any(Path(f"{aside}{s}").exists() for s in names):
        n += 1
        aside = p.with_name(f"{p.name}.damaged.{n}")
    for s in names:
        if Path(f"{p}{s}").exists():
            Path(f"{p}{s}").rename(f"{aside}{s}")
    return aside
