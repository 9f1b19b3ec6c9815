"""The sidecar database as a file: its writer's schema checked against this version's (a sidecar
of another version is set aside and built anew, never migrated), and the writer leaving WAL when
it closes, so the sidecar is one self-contained file that a reader on read-only media can open."""

from __future__ import annotations

import os
import sqlite3
import time
from pathlib import Path

LEAVE_WAL_S = 60.0  # the writer's busy timeout: how long close() tries to leave WAL
_TRY_EVERY_S = 0.1


class SidecarInUseError(sqlite3.OperationalError):
    """The writer could not leave WAL when it closed: another connection held the sidecar open
    (``path``; ``holders``: the processes seen holding it). The file is not self-contained (a
    reader on read-only media cannot open it; its latest pages may be only in ``-wal``)."""

    def __init__(self, path: Path, holders: list[str], checkpointed: bool) -> None:
        self.path = path
        self.holders = holders
        held = ", ".join(holders) or "another process"
        where = (
            "its features are in the file, but it is still in WAL mode"
            if checkpointed
            else f"its latest features are only in {path.name}-wal"
        )
        super().__init__(
            f"{path}: not left one self-contained file: {where} (held open by {held}); "
            "close that reader and run the build again (it only finishes the file)"
        )


def sqlite_code(exc: BaseException) -> int:
    """SQLite's primary result code of ``exc`` (``SQLITE_BUSY``, ``SQLITE_CORRUPT``...); 0 for
    an error the sqlite3 module raises itself (a closed connection, misuse), which has none."""
    code = getattr(exc, "sqlite_errorcode", None)
    return code & 0xFF if isinstance(code, int) else 0


def schema_mismatch(db: sqlite3.Connection, schema: str) -> str | None:
    """How the tables of ``db`` differ from those ``schema`` creates (a sidecar of another
    version: a column missing or one more), None when they are the same."""
    expected = sqlite3.connect(":memory:")
    try:
        expected.executescript(schema)
        tables = expected.execute("SELECT name FROM sqlite_master WHERE type='table'")
        for (table,) in tables.fetchall():
            want, have = (_columns(c, table) for c in (expected, db))
            if want != have:
                differs = [f"no column {c}" for c in want if c not in have]
                differs += [f"a column {c} this version lacks" for c in have if c not in want]
                how = ", ".join(differs) or "columns in another order"
                return f"schema of another version ({table}: {how}); its features cannot be kept"
    finally:
        expected.close()
    return None


def _columns(db: sqlite3.Connection, table: str) -> list[str]:
    return [str(r[1]) for r in db.execute(f"PRAGMA table_info({table})")]


def leave_wal(db: sqlite3.Connection, path: Path, wait_s: float = LEAVE_WAL_S) -> None:
    """Checkpoint every page of the writer's connection ``db`` into the sidecar ``path`` and
    switch its journal back to DELETE, tried again for ``wait_s`` while another connection holds
    it; SidecarInUseError naming the holders when it still cannot (errors other than a lock
    raised as they are)."""
    deadline = time.monotonic() + max(0.0, wait_s)
    db.execute(f"PRAGMA busy_timeout={int(_TRY_EVERY_S * 1000)}")  # a try never waits longer
    checkpointed = False
    while True:
        try:
            busy = db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
            checkpointed = checkpointed or (busy is not None and busy[0] == 0)
            mode = db.execute("PRAGMA journal_mode=DELETE").fetchone()
            if mode is not None and str(mode[0]).lower() == "delete":
                return
        except sqlite3.OperationalError as exc:
            if sqlite_code(exc) not in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED):
                raise
        if time.monotonic() >= deadline:
            raise SidecarInUseError(path, holders(path), checkpointed)
        time.sleep(_TRY_EVERY_S)


def holders(path: Path) -> list[str]:
    """The processes with the database ``path`` (or its ``-wal`` / ``-shm``) open, as
    ``pid N (command)``, this one as ``this process (pid N)``; those Linux's /proc shows."""
    names = {Path(f"{path}{s}").resolve() for s in ("", "-wal", "-shm")}
    found = []
    for pid in sorted(int(p.name) for p in _entries(Path("/proc")) if p.name.isdigit()):
        if not any(_target(fd) in names for fd in _entries(Path(f"/proc/{pid}/fd"))):
            continue
        if pid == os.getpid():
            found.append(f"this process (pid {pid})")
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, UnicodeDecodeError):
            cmd = ""
        found.append(f"pid {pid} ({' '.join(cmd.split())[:80] or '?'})")
    return found


def _entries(folder: Path) -> list[Path]:
    try:
        return list(folder.iterdir())
    except OSError:
        return []


def _target(link: Path) -> Path | None:
    try:
        return link.readlink()
    except OSError:
        return None
