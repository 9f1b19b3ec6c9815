"""Reading the injected clock so that a clock gone bad mid-run cannot fail a frame or an FDR record.

The matcher checks its clock once, at start-up (``health.clock_problem``). A clock can still go
bad later: a call that raises, a float, a negative number. ``SteadyClock`` stands between the
clock and what reads it (a frame's health update and result, the FDR's ``recorded_at_ns``): a
numpy integer is taken as its ``int``; any other reading that is not whole nanoseconds >= 0 is
replaced by the last good reading advanced by this process's own monotonic clock, and the
first such reading of an outage is kept as a ``ClockProblem`` for the reader to log (one
WARNING ``CLOCK_UNUSABLE`` per outage). A reading that went back is no problem here: the
health window restarts on it and says so (``health.CLOCK_STEPPED_BACK``).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import cast

import numpy as np
from loguru import logger

from c3_matcher.protocols import Clock

__all__ = [
    "CLOCK_UNUSABLE",
    "ClockProblem",
    "SteadyClock",
    "read_raw",
    "read_said",
    "reading_problem",
]

CLOCK_UNUSABLE = "c3.matcher.clock_unusable"
"""The kind of the WARNING said when the matcher's clock gives no usable reading mid-run."""


def read_raw(clock: Clock) -> tuple[object, str | None]:
    """What ``clock.monotonic_ns()`` gave, as it gave it; or, when the call raised, why."""
    try:
        return clock.monotonic_ns(), None
    except Exception as exc:
        return None, f"monotonic_ns() raised {type(exc).__name__}: {exc}"


def reading_problem(value: object) -> str | None:
    """Why ``value``, read from ``monotonic_ns()``, is not whole nanoseconds >= 0 as a Python
    ``int`` (None: it is). A bool, a float and a numpy integer are not."""
    if type(value) is not int:
        return f"monotonic_ns() gave {value!r} ({type(value).__name__}), not an int of nanoseconds"
    if value < 0:
        return f"monotonic_ns() gave {value}, not nanoseconds >= 0"
    return None


@dataclass(frozen=True, slots=True)
class ClockProblem:
    """A reading that could not be used: why, and the reading given instead (``used_ns``)."""

    problem: str
    used_ns: int

    def log(self) -> None:
        """The one WARNING of this outage (loguru directly: the FDR logs it too, and the log
        module imports the FDR)."""
        logger.bind(kind=CLOCK_UNUSABLE, problem=self.problem, used_ns=self.used_ns).warning(
            f"the matcher's clock gave no usable reading ({self.problem}): its frames and FDR "
            "records are timed from its last good reading on by this process's monotonic "
            "clock until it gives whole nanoseconds >= 0 again"
        )


class SteadyClock:
    """``clock`` read so that ``monotonic_ns`` always gives an ``int`` >= 0 (module docstring).
    Thread-safe: a frame, a health monitor and the FDR may read it at once."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._last: tuple[int, int] | None = None  # the last good reading, this process's then
        self._failing = False  # the outage now under way is kept (or said) already
        self._unsaid: ClockProblem | None = None
        self._lock = threading.Lock()

    @classmethod
    def of(cls, clock: Clock) -> SteadyClock:
        """``clock`` itself when it is one already (so that those sharing it share one outage),
        else one over it."""
        return clock if isinstance(clock, SteadyClock) else cls(clock)

    def monotonic_ns(self) -> int:
        value, raised = read_raw(self._clock)
        if raised is not None:
            return self._instead(raised)
        if isinstance(value, np.integer):
            value = int(value)
        if (problem := reading_problem(value)) is not None:
            return self._instead(problem)
        now = cast(int, value)  # reading_problem found it an int >= 0
        with self._lock:
            self._last, self._failing = (now, time.monotonic_ns()), False
        return now

    def _instead(self, problem: str) -> int:
        """The reading given for a bad one: the last good one advanced by this process's clock
        (this process's clock itself before any), the outage's first problem kept."""
        with self._lock:
            now = time.monotonic_ns()
            used = now if self._last is None else self._last[0] + now - self._last[1]
            if not self._failing:
                self._failing, self._unsaid = True, ClockProblem(problem, used)
            return used

    def take_problem(self) -> ClockProblem | None:
        """The outage's problem not yet logged, if any (taken: it is logged once)."""
        with self._lock:
            unsaid, self._unsaid = self._unsaid, None
            return unsaid


def read_said(clock: Clock) -> int:
    """One reading of ``clock`` through a ``SteadyClock`` (``clock`` itself when it is one),
    its problem, when it is the first of an outage, logged at once."""
    steady = SteadyClock.of(clock)
    now = steady.monotonic_ns()
    if (problem := steady.take_problem()) is not None:
        problem.log()
    return now
