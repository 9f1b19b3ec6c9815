"""Frames take turns, and what records a frame stays open until the frame is done.

``FrameTurns`` admits one frame at a time, in the order the calls came (a caller that waits is
never overtaken by a later one), and is closed once: ``close()`` refuses every later turn at
once, callers still waiting included, and waits only for the frame in progress. Called from
that frame's own thread (a signal handler's clean shutdown while the flight loop is inside
``match``), ``close()`` cannot wait for it: it returns at once and the frame goes on; every sink
closed meanwhile on that thread (the recorder, the log sinks: ``close_after_frame``) is closed
once the frame is done, so the frame keeps its records.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator

__all__ = ["FrameTurns", "close_after_frame"]

_frame = threading.local()  # ``closes``: the sink closes waiting for this thread's frame to end


def close_after_frame(close: Callable[[], None]) -> bool:
    """Keep ``close`` for the end of the frame this thread is in (True); False when it is in
    none: the caller closes now."""
    closes: list[Callable[[], None]] | None = getattr(_frame, "closes", None)
    if closes is None:
        return False
    closes.append(close)
    return True


class FrameTurns:
    """The turns of one matcher's frames (module docstring). ``on_close_error`` hears what a
    close kept for the end of a frame raised (its caller has returned by then)."""

    def __init__(self, on_close_error: Callable[[Exception], None]) -> None:
        # reentrant: a signal handler may call close() while its thread holds the lock
        self._cond = threading.Condition(threading.RLock())
        self._waiting: list[object] = []  # the callers waiting, first come first
        self._owner: int | None = None  # the thread whose frame is in progress
        self._closing = False
        self._on_close_error = on_close_error

    @contextlib.contextmanager
    def turn(self) -> Iterator[bool]:
        """This thread's turn, once the frames called before it are done: True, or False when
        closed (the caller refuses). A call from within this thread's own frame (a signal
        handler's) runs inside it, as a nested call always did."""
        if self._owner == threading.get_ident():
            yield not self._closing
            return
        outermost = getattr(_frame, "closes", None) is None  # sink closes wait for it
        if outermost:
            _frame.closes = []
        admitted = False
        try:
            admitted = self._admit()
            yield admitted
        finally:
            try:
                if outermost:
                    self._run_closes()
            finally:
                if admitted:
                    with self._cond:
                        self._owner = None
                        self._cond.notify_all()

    def close(self) -> None:
        """Refuse every later turn, the callers waiting included; wait for the frame in
        progress, unless it is this thread's (it closes when that frame is done). Idempotent."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
            if self._owner == threading.get_ident():
                return
            while self._owner is not None:
                self._cond.wait()

    def _admit(self) -> bool:
        """Wait for this caller's turn (first come, first served); False when closed."""
        ticket = object()
        with self._cond:
            self._waiting.append(ticket)
            try:
                while not self._closing and (
                    self._owner is not None or self._waiting[0] is not ticket
                ):
                    self._cond.wait()
            finally:
                self._waiting.remove(ticket)
                self._cond.notify_all()
            if self._closing:
                return False
            self._owner = threading.get_ident()
            return True

    def _run_closes(self) -> None:
        closes, _frame.closes = _frame.closes, None
        for close in closes:
            try:
                close()
            except Exception as exc:
                self._on_close_error(exc)
