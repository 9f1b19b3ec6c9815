"""What a path that is not a regular file is, in words: the one reading of ``stat`` that every
refusal of one uses (an image, a tile store, the FDR's live segment, a store being written).
Judged by ``stat`` (links followed), never opened: opening a FIFO waits for a writer, and a
device such as ``/dev/zero`` never ends."""

from __future__ import annotations

import stat
from pathlib import Path

__all__ = ["kind_of", "special_kind"]

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
)


def kind_of(mode: int) -> str | None:
    """What a file of ``mode`` (``st_mode``) is when it is not a regular file ("a directory",
    "a FIFO", ...); None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "no regular file")


def special_kind(path: Path) -> str | None:
    """What ``path`` is when it exists and is not a regular file; None for a regular file, or
    nothing there (or nothing that can be looked at: whoever opens it next says why)."""
    try:
        return kind_of(path.stat().st_mode)
    except OSError:
        return None
