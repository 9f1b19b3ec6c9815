"""A minimal progress bar on stderr (stdout carries only results)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["ProgressBar"]


class ProgressBar:
    """``bar(done, total)`` redraws ``label [#####.....] done/total  elapsed  eta`` in place
    when the stream is a terminal, else prints a line every ``every`` steps and at the end.
    Progress is only shown: a stream that cannot be written (a full log disk, a closed pipe)
    stops the bar, never the run it reports on."""

    def __init__(self, label: str, stream: TextIO | None = None, every: int = 10) -> None:
        self._label = label
        self._stream = stream if stream is not None else sys.stderr
        self._every = max(1, every)
        self._started = time.perf_counter()
        self._writable = True
        try:
            self._tty = bool(getattr(self._stream, "isatty", lambda: False)())
        except ValueError:  # closed
            self._tty = self._writable = False

    def __call__(self, done: int, total: int) -> None:
        if not self._writable:
            return
        try:
            self._draw(done, total)
        except (OSError, ValueError):  # ValueError: the stream was closed
            self._writable = False

    def _draw(self, done: int, total: int) -> None:
        elapsed = time.perf_counter() - self._started
        eta = elapsed / done * (total - done) if done else 0.0
        width = 30
        filled = round(width * done / max(total, 1))
        line = (
            f"{self._label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
            f"{elapsed:6.1f}s eta {eta:6.1f}s"
        )
        if self._tty:
            self._stream.write("\r" + line + ("\n" if done >= total else ""))
        elif done % self._every == 0 or done >= total or done == 1:
            self._stream.write(line + "\n")
        self._stream.flush()
