"""RollingHealthWindow: consecutive low-inlier frames and the 60 s mean, on an injected clock."""

from __future__ import annotations

import sys
import threading
from collections import deque
from collections.abc import Callable, Iterator

import pytest

from c3_matcher.dto import MatcherHealth
from c3_matcher.errors import InvalidInputError
from c3_matcher.health import HealthUpdate, RollingHealthWindow
from c3_matcher.testing import FakeClock


def test_consecutive_low_inlier_counts_and_resets():
    clock = FakeClock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60)
    for count in (10, 0, 59):
        window.update(clock.monotonic_ns(), count, False)
        clock.advance(0.33)
    assert window.snapshot().consecutive_low_inlier == 3
    window.update(clock.monotonic_ns(), 60, False)
    assert window.snapshot().consecutive_low_inlier == 0


def test_mean_over_sixty_seconds_evicts_old_updates():
    clock = FakeClock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60)
    window.update(clock.monotonic_ns(), 300, False)
    clock.advance(30)
    window.update(clock.monotonic_ns(), 100, True)
    assert window.snapshot().mean_inliers_60s == pytest.approx(200.0)
    clock.advance(31)  # the first update is now 61 s old
    assert window.snapshot().mean_inliers_60s == pytest.approx(100.0)
    clock.advance(60)
    assert window.snapshot().mean_inliers_60s == 0.0


def test_an_update_exactly_sixty_seconds_old_is_out_of_the_window():
    """The window is the last 60 s, its start excluded: an update 60 s old no longer counts,
    one a nanosecond younger still does."""
    clock = FakeClock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60)
    window.update(clock.monotonic_ns(), 100, False)
    clock.now_ns += 60 * 1_000_000_000 - 1
    assert window.snapshot().mean_inliers_60s == 100.0
    clock.now_ns += 1
    assert window.snapshot().mean_inliers_60s == 0.0


def test_update_count_and_validation():
    clock = FakeClock()
    window = RollingHealthWindow(clock, 60)
    window.update(clock.monotonic_ns(), 5, True)
    assert window.update_count == 1 and window.last_update is not None
    assert window.last_update.had_backbone_error is True
    with pytest.raises(InvalidInputError, match="best_inlier_count"):
        window.update(clock.monotonic_ns(), -1, False)


def test_a_monitor_thread_may_read_health_while_frames_update_it():
    """A GNC monitor polling ``health_snapshot()`` beside the matcher's thread: the window's
    deque was read while it was appended to and evicted ("deque mutated during iteration",
    or an IndexError from a pop on an empty deque)."""
    clock = FakeClock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60, window_s=1.0)
    errors: list[BaseException] = []
    stop = threading.Event()

    def monitor() -> None:
        while not stop.is_set():
            try:
                window.snapshot()
                window.last_update  # noqa: B018 - read as a monitor would
            except Exception as exc:  # the failure under test
                errors.append(exc)
                return

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as the interpreter allows
    thread = threading.Thread(target=monitor)
    thread.start()
    try:
        for i in range(60_000):
            clock.now_ns = i * 1_000_000  # one frame a millisecond: 1000 in the window
            window.update(clock.now_ns, i % 100, False)
            if errors:
                break
    finally:
        stop.set()
        thread.join()
        sys.setswitchinterval(interval)
    assert errors == []
    assert window.update_count == 60_000


class _PausingUpdates(deque[HealthUpdate]):
    """The window's updates, iterated with a pause after the first: ``pause()`` runs there, in
    the reading thread, once (an update landing mid-read is then certain, not a matter of
    thread timing)."""

    def __init__(self, items: list[HealthUpdate], pause: Callable[[], None]) -> None:
        super().__init__(items)
        self._pause: Callable[[], None] | None = pause

    def __iter__(self) -> Iterator[HealthUpdate]:
        it = super().__iter__()
        for i, item in enumerate(it):
            yield item
            if i == 0 and self._pause is not None:
                pause, self._pause = self._pause, None
                pause()


def test_an_update_is_held_off_while_a_snapshot_reads_the_window():
    """A monitor's ``snapshot()`` stopped halfway through reading the updates (an Event
    handshake, no timing): the window's lock is held, so the frame's ``update`` from another
    thread waits until the read is done; the snapshot is the window as it was before it. Read
    without the lock, the update landed mid-read ("deque mutated during iteration")."""
    clock = FakeClock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60)
    paused, resume = threading.Event(), threading.Event()

    def pause() -> None:
        paused.set()
        resume.wait()

    before = [HealthUpdate(k, count, False) for k, count in enumerate((10, 20, 30, 40))]
    window._updates = _PausingUpdates(before, pause)  # the read made to pause
    clock.now_ns = 10
    seen: list[MatcherHealth | Exception] = []

    def monitor() -> None:
        try:
            seen.append(window.snapshot())
        except Exception as exc:  # the failure under test
            seen.append(exc)
        finally:
            paused.set()  # a read that never paused leaves no one waiting

    reader = threading.Thread(target=monitor)
    reader.start()
    paused.wait()
    held = window._lock.locked()  # whether the read holds it
    frame = threading.Thread(target=window.update, args=(clock.now_ns, 500, False))
    frame.start()  # held off by the lock, it lands once the read is done
    if not held:  # nothing holds it off: it lands now, mid-read
        frame.join()
    resume.set()
    reader.join()
    frame.join()
    assert held, "snapshot() read the updates without the window's lock"
    assert len(seen) == 1 and isinstance(seen[0], MatcherHealth), seen
    assert seen[0].mean_inliers_60s == pytest.approx(25.0)  # the four before the update
    assert window.snapshot().mean_inliers_60s == pytest.approx(120.0)  # and then with it
