"""What the log and video libraries print, kept from the terminal: a command's failure is one
line of its own, and its ``--json`` output is the only thing on stdout."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterator

__all__ = ["quiet"]


@contextlib.contextmanager
def quiet(chatter: io.StringIO) -> Iterator[None]:
    """Everything printed inside the block goes into ``chatter``: Python's prints (stdout and
    stderr), and what compiled code writes to the process's own stderr (pymavlink's DataFlash
    indexer, a line per damaged header; FFmpeg inside OpenCV, a line per damaged packet)."""
    with (
        tempfile.TemporaryFile() as native,
        contextlib.redirect_stdout(chatter),
        contextlib.redirect_stderr(chatter),
    ):
        if sys.__stderr__ is not None:
            sys.__stderr__.flush()
        saved = os.dup(2)
        os.dup2(native.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            native.seek(0)
            chatter.write(native.read().decode("utf-8", "replace"))
