"""RollingHealthWindow: consecutive low-inlier frames and the 60 s mean, on an injected clock."""

from __future__ import annotations

import sys
import threading

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.health import RollingHealthWindow
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
