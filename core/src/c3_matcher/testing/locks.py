"""A real second process holding an SQLite database in EXCLUSIVE locking mode (fault tests:
a tile store or features sidecar another program has locked)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["exclusive_lock", "release"]

_HOLDER = """
import sqlite3, sys
db = sqlite3.connect(sys.argv[1], isolation_level=None)
db.execute("PRAGMA locking_mode=EXCLUSIVE")
db.execute("BEGIN EXCLUSIVE")
version = db.execute("PRAGMA user_version").fetchone()[0]
db.execute(f"PRAGMA user_version={version}")  # a write: every other connection is locked out
print("locked", flush=True)
sys.stdin.readline()
db.execute("ROLLBACK")
db.close()
"""


@contextmanager
def exclusive_lock(path: str | Path) -> Iterator[subprocess.Popen[str]]:
    """Hold ``path`` locked (``PRAGMA locking_mode=EXCLUSIVE``, an exclusive transaction that
    writes nothing new, rolled back) from another process for the duration of the block; the
    lock is released (and the process gone) on exit, or earlier with :func:`release`."""
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        line = holder.stdout.readline().strip() if holder.stdout is not None else ""
        if line != "locked":
            raise RuntimeError(f"could not lock {path} from a second process")
        yield holder
    finally:
        release(holder)


def release(holder: subprocess.Popen[str]) -> None:
    """Release the lock: the holder rolls back, closes and exits."""
    if holder.poll() is None:
        try:
            if holder.stdin is not None:
                holder.stdin.write("\n")
                holder.stdin.flush()
            holder.wait(timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            holder.kill()
            holder.wait()
