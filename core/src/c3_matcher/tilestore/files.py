"""Store files (an MBTiles store, a map-features sidecar): why one cannot be opened, in words a
user can act on, found before SQLite is asked: SQLite says "unable to open database file" for a
missing file, a directory and a permission problem alike."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from c3_matcher.file_kinds import kind_of

__all__ = ["MMAP_BYTES", "cannot_open", "open_failure", "read_only_uri", "set_aside"]

MMAP_BYTES = 256 * 1024 * 1024
"""The memory map of a read connection to a store file (tile store and map-features sidecar)."""

_COMPANIONS = ("-wal", "-shm", "-journal")  # SQLite's files beside a database, by suffix


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
        os.close(os.open(p, os.O_RDONLY))
    except OSError as exc:
        return cannot_open(exc)
    return None


def read_only_uri(path: str | Path) -> str:
    """The SQLite URI that opens the database file ``path`` read-only (``uri=True``): the
    absolute path percent-encoded, so that a ``#``, ``?`` or ``%`` in a folder's name is part of
    the name, not a fragment, a query or an escape (which would open another file, or drop
    ``mode=ro``)."""
    return f"{Path(path).resolve().as_uri()}?mode=ro"


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
