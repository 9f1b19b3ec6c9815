"""SQLite statements of a store file (an MBTiles store, a features sidecar) that end: each runs
within a time bound and stops for Ctrl-C or SIGTERM.

A store file is input: its ``tiles`` may be a view (MBTiles allows it), and a view may never
end (a recursive one), so any statement on it could run for ever inside SQLite's C code, where
Python's signal handlers never run. SQLite's progress handler, called every ``STEPS`` steps of a
statement, ends it when its bound has passed (:class:`QueryTimeoutError`) and gives Python the
chance to run a signal handler, whose exception (``KeyboardInterrupt``, the CLI's SIGTERM) the
sqlite3 module would swallow: it is caught, the statement ended, and the exception raised
where the statement was (:meth:`BoundedConnection.within`).

The bounds, each far above what a store of any size needs, since each statement so bounded
is an index seek or a small table's read: ``OPEN_S`` for reading a store file as at open (its
tables, columns, smallest and largest zoom, metadata; 0.2 ms for a shipped store, a few ms
cold) and ``READ_S`` for one read in flight (a tile: 20 µs warm; a sidecar row of about a
megabyte: milliseconds from slow media; both above the lock wait of a read). Listings whose
length grows with the store (every tile of a zoom, every window of a set) have none
(``UNBOUNDED``): they only stop for a signal.
"""

from __future__ import annotations

import math
import sqlite3
import time
from collections.abc import Iterator
from typing import Any, Final

__all__ = ["OPEN_S", "READ_S", "STEPS", "UNBOUNDED", "BoundedConnection", "QueryTimeoutError"]

OPEN_S: Final = 5.0  # reading a store file as at open: its shape checks and metadata
READ_S: Final = 0.5  # one read in flight: a tile, a sidecar row or set, a probe of a store
UNBOUNDED: Final = math.inf  # a listing of the whole store: stopped by a signal only
STEPS: Final = 1000  # SQLite steps between two looks at the clock: some microseconds


class QueryTimeoutError(sqlite3.OperationalError):
    """A statement on a store file ran past its bound and was ended."""


class _Watch:
    """What the progress handler of one connection looks at: the deadline of the statements
    running now, and a signal handler's exception caught while one ran (``stop``)."""

    def __init__(self) -> None:
        self.deadline = math.inf
        self.late = False
        self.stop: BaseException | None = None

    def ticks(self) -> Iterator[int]:
        """The progress handler, as a generator's ``__next__``: 1 (end the statement) when the
        deadline has passed or a signal handler raised. A signal handler runs where the
        generator resumes, inside the ``try``, so its exception is kept, not swallowed."""
        clock = time.monotonic
        while True:
            try:
                self.late = self.late or clock() > self.deadline
                yield 1 if self.late or self.stop is not None else 0
            except GeneratorExit:
                return
            except BaseException as exc:  # a signal handler's (Ctrl-C, SIGTERM)
                self.stop = exc


class BoundedConnection(sqlite3.Connection):
    """An SQLite connection (``sqlite3.connect(..., factory=BoundedConnection)``) whose
    statements run in :meth:`within` end within a bound and stop for a signal."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._watch = _Watch()
        ticks = self._watch.ticks()
        next(ticks)  # started here, where a pending signal's exception is raised as usual
        self._handler = ticks.__next__
        self._outer: list[float] = []  # the deadlines of enclosing ``within``s

    def within(self, seconds: float, what: str) -> _Within:
        """A context in which every statement of this connection ends ``seconds`` after it is
        entered at the latest (QueryTimeoutError saying ``what`` did not finish), and one
        running when Ctrl-C or SIGTERM comes ends, raising the signal's exception."""
        return _Within(self, seconds, what)

    def _arm(self, seconds: float) -> None:
        watch = self._watch
        if not self._outer:
            self.set_progress_handler(self._handler, STEPS)
        self._outer.append(watch.deadline)
        watch.deadline = min(watch.deadline, time.monotonic() + seconds)

    def _disarm(self, exc: BaseException | None, seconds: float, what: str) -> None:
        """Leave a ``within``: the signal's exception caught meanwhile raised, or a statement
        the deadline ended raised as QueryTimeoutError."""
        watch = self._watch
        watch.deadline = self._outer.pop()
        if not self._outer:
            self.set_progress_handler(None, 0)
        late, stop = watch.late, watch.stop
        watch.late, watch.stop = False, None
        if stop is not None:
            raise stop
        if late and isinstance(exc, sqlite3.OperationalError):
            raise QueryTimeoutError(f"{what} took longer than {seconds:g} s and was ended") from exc


class _Within:
    """The context of :meth:`BoundedConnection.within`."""

    __slots__ = ("_db", "_seconds", "_what")

    def __init__(self, db: BoundedConnection, seconds: float, what: str) -> None:
        self._db, self._seconds, self._what = db, seconds, what

    def __enter__(self) -> None:
        self._db._arm(self._seconds)

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        self._db._disarm(exc, self._seconds, self._what)
