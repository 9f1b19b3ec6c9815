"""A file opened for reading only when it is a regular file, never waited on: ``open`` of a
FIFO waits for a writer (forever, in flight), so a path judged by ``stat`` and replaced by a
FIFO before it is opened would hang whoever opens it. :func:`open_regular` opens without
waiting (``O_NONBLOCK``: a FIFO's open returns at once) and judges what it opened (``fstat``):
nothing can be swapped in between."""

from __future__ import annotations

import os
from pathlib import Path

from c3_matcher.file_kinds import kind_of

__all__ = ["SpecialFileError", "open_regular"]


class SpecialFileError(OSError):
    """What a path opened to read is no regular file: a FIFO, a device, a directory (``kind``,
    in :func:`~c3_matcher.file_kinds.kind_of`'s words). Its text is ``it is <kind>``."""

    def __init__(self, kind: str) -> None:
        super().__init__(f"it is {kind}")
        self.kind = kind


def open_regular(path: str | Path, flags: int = os.O_RDONLY) -> int:
    """A descriptor of ``path`` opened with ``flags`` (read-only by default; made 0o644 where
    ``O_CREAT`` creates it; blocking I/O), when it is a regular file; SpecialFileError when it is
    not, the OSError of ``open`` when it cannot be opened. The caller closes it."""
    fd = os.open(path, flags | os.O_NONBLOCK, 0o644)
    try:
        kind = kind_of(os.fstat(fd).st_mode)
        if kind is not None:
            raise SpecialFileError(kind)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd
