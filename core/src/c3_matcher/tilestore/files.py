"""Why a store file (an MBTiles store, a map-features sidecar) cannot be opened, in words a
user can act on, found before SQLite is asked: SQLite says "unable to open database file" for a
missing file, a directory and a permission problem alike."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

__all__ = ["cannot_open", "open_failure"]


def open_failure(path: str | Path, kind: str) -> str | None:
    """Why ``path`` cannot be opened for reading as ``kind`` (e.g. ``"an MBTiles file"``):
    ``"no such file"``, ``"is a directory, not <kind>"``, ``"not a regular file, not
    <kind>"``, ``"cannot open (permission denied)"`` or ``"cannot open (<the system's
    words>)"``; None when it opens."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:  # a folder on the way without search permission, a loop of links
        return cannot_open(exc)
    if stat.S_ISDIR(st.st_mode):
        return f"is a directory, not {kind}"
    if not stat.S_ISREG(st.st_mode):  # a pipe or a device: opening it could block
        return f"not a regular file, not {kind}"
    try:
        os.close(os.open(p, os.O_RDONLY))
    except OSError as exc:
        return cannot_open(exc)
    return None


def cannot_open(exc: OSError) -> str:
    """``"cannot open (<why>)"`` for an OSError: ``permission denied`` for EACCES / EPERM."""
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "cannot open (permission denied)"
    return f"cannot open ({(exc.strerror or str(exc)).lower()})"
