"""Files replaced whole or not at all: a writer gets a temporary file of its own beside the
target, fsynced and renamed over it (the rename then fsynced in the directory) when the block
ends; on any exception (a full disk, a file size limit, Ctrl-C) the temporary file is removed
and the target keeps what it held before. Results, reports and pictures are written this way."""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, TextIO, cast

from c3_matcher.fdr.files import fsync_dir

__all__ = ["atomic_writer", "write_bytes_atomically", "write_text_atomically"]


@contextlib.contextmanager
def _replacing(path: Path, mode: str) -> Iterator[IO[Any]]:
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, mode, encoding=None if "b" in mode else "utf-8") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_writer(path: Path) -> Iterator[TextIO]:
    """A UTF-8 text file to write ``path`` through (module docstring)."""
    with _replacing(path, "w") as fh:
        yield cast(TextIO, fh)


def write_text_atomically(path: Path, text: str) -> Path:
    """``path`` holding ``text`` (UTF-8), replaced whole (module docstring)."""
    with atomic_writer(path) as fh:
        fh.write(text)
    return path


def write_bytes_atomically(path: Path, data: bytes) -> Path:
    """``path`` holding ``data``, replaced whole (module docstring)."""
    with _replacing(path, "wb") as fh:
        fh.write(data)
    return path
