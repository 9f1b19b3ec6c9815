"""``RollingHealthWindow``: the matcher's health signal for C5 (AC-NEW-7 cache-poisoning safety)."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

from c3_matcher.clocks import SteadyClock, read_raw, reading_problem
from c3_matcher.dto import MatcherHealth
from c3_matcher.errors import InvalidInputError
from c3_matcher.protocols import Clock

__all__ = [
    "CLOCK_STEPPED_BACK",
    "HealthUpdate",
    "MonotonicClock",
    "RollingHealthWindow",
    "SteadyClock",
    "clock_problem",
]

NS_PER_S = 1_000_000_000
CLOCK_STEPPED_BACK = "c3.matcher.clock_stepped_back"
"""The kind of the WARNING said when the matcher's clock reads before its last health update."""


class MonotonicClock:
    """The production clock: ``time.monotonic_ns``."""

    def monotonic_ns(self) -> int:
        return time.monotonic_ns()


def clock_problem(clock: Clock) -> str | None:
    """Why ``clock`` cannot time the matcher's frames (None: it can), read once at start-up:
    its ``monotonic_ns()`` must give whole nanoseconds >= 0 as a Python ``int``
    (``clocks.reading_problem``). A clock that goes bad later is read through a
    ``clocks.SteadyClock``, which times the frames and records on from its last good reading."""
    now, raised = read_raw(clock)
    return raised or reading_problem(now)


@dataclass(frozen=True, slots=True)
class HealthUpdate:
    """One ``update`` call, as recorded (kept for the window and for inspection)."""

    at_ns: int
    best_inlier_count: int
    had_backbone_error: bool


class RollingHealthWindow:
    """Counts consecutive low-inlier frames and the mean best-inlier count over a time window.

    A frame is "low" when its best inlier count is below ``low_inlier_threshold`` (the matcher's
    ``min_inliers_threshold``; an InsufficientInliersError frame reports 0). ``mean_inliers_60s``
    averages the best inlier counts of the updates within the last ``window_s`` seconds of the
    injected clock (0.0 when there are none). Safe across threads: a monitor may read
    ``snapshot()`` while the matcher's thread updates (each call holds the window's own lock for
    microseconds, never for a frame).
    """

    def __init__(self, clock: Clock, low_inlier_threshold: int, window_s: float = 60.0) -> None:
        if low_inlier_threshold < 0:
            raise InvalidInputError("low_inlier_threshold", "must be >= 0")
        if window_s <= 0:
            raise InvalidInputError("window_s", "must be > 0")
        self._clock = clock
        self._threshold = low_inlier_threshold
        self._window_ns = int(window_s * NS_PER_S)
        self._updates: deque[HealthUpdate] = deque()
        self._consecutive_low = 0
        self._update_count = 0
        self._lock = threading.Lock()

    @property
    def update_count(self) -> int:
        """How many times ``update`` was called."""
        return self._update_count

    @property
    def last_update(self) -> HealthUpdate | None:
        with self._lock:
            return self._updates[-1] if self._updates else None

    def update(self, now_ns: int, best_inlier_count: int, had_backbone_error: bool) -> None:
        if best_inlier_count < 0:
            raise InvalidInputError("best_inlier_count", f"must be >= 0, got {best_inlier_count}")
        with self._lock:
            self._update_count += 1
            self._evict(now_ns)  # first: a clock stepped back empties the window
            self._updates.append(HealthUpdate(now_ns, best_inlier_count, had_backbone_error))
            if best_inlier_count < self._threshold:
                self._consecutive_low += 1
            else:
                self._consecutive_low = 0
            self._evict(now_ns)

    def snapshot(self) -> MatcherHealth:
        now_ns = self._clock.monotonic_ns()
        with self._lock:
            self._evict(now_ns)
            counts = [u.best_inlier_count for u in self._updates]
            consecutive_low = self._consecutive_low
        mean = float(sum(counts) / len(counts)) if counts else 0.0
        return MatcherHealth(consecutive_low_inlier=consecutive_low, mean_inliers_60s=mean)

    def _evict(self, now_ns: int) -> None:
        """The updates older than the window dropped; all of them when the clock now reads
        before the last (it stepped back: a wall clock given for the monotonic one, a reset),
        since how long ago they were is then unknown, and counting them would keep a mean no
        frame made lately (said once a step, WARNING ``c3.matcher.clock_stepped_back``)."""
        if self._updates and self._updates[-1].at_ns > now_ns:
            stepped_ns = self._updates[-1].at_ns - now_ns
            self._updates.clear()
            from c3_matcher.logs import log_event

            log_event(
                "WARNING",
                CLOCK_STEPPED_BACK,
                f"the matcher's clock stepped back {stepped_ns / NS_PER_S:.3f} s: the health "
                "window restarts empty (give compose_root a monotonic clock)",
                stepped_back_ns=stepped_ns,
            )
        horizon = now_ns - self._window_ns
        while self._updates and self._updates[0].at_ns <= horizon:
            self._updates.popleft()
