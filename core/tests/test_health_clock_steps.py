"""The health window under a clock that steps back: frames from before the step are not counted
(how long ago they were is unknown), and the step is said once (WARNING)."""

from __future__ import annotations

import pytest

from c3_matcher.health import CLOCK_STEPPED_BACK, NS_PER_S, RollingHealthWindow
from c3_matcher.testing.fakes import InMemoryFdr, ScriptedCandidate, ScriptedRig


class _Clock:
    def __init__(self) -> None:
        self.now_ns = 0

    def monotonic_ns(self) -> int:
        return self.now_ns


def test_a_clock_stepped_back_empties_the_window_and_is_said_once(
    caplog_kinds: list[str],
) -> None:
    clock = _Clock()
    window = RollingHealthWindow(clock, low_inlier_threshold=60)
    clock.now_ns = 3600 * NS_PER_S
    window.update(clock.now_ns, 500, False)
    clock.now_ns = 310 * NS_PER_S  # stepped back an hour, then five minutes with no frame
    assert window.snapshot().mean_inliers_60s == 0.0
    assert caplog_kinds.count(CLOCK_STEPPED_BACK) == 1
    window.update(clock.now_ns, 200, False)  # the new timeline counts
    assert window.snapshot().mean_inliers_60s == 200.0
    assert caplog_kinds.count(CLOCK_STEPPED_BACK) == 1


def test_the_pipeline_counts_no_fix_from_before_the_step() -> None:
    rig = ScriptedRig([ScriptedCandidate(inliers=500)], InMemoryFdr())
    rig.clock.now_ns = 3600 * NS_PER_S
    rig.match()
    rig.clock.now_ns = 10 * NS_PER_S
    rig.clock.advance(300)
    assert rig.pipeline.health_snapshot().mean_inliers_60s == 0.0


@pytest.fixture
def caplog_kinds() -> list[str]:
    from loguru import logger

    kinds: list[str] = []
    sink = logger.add(lambda m: kinds.append(m.record["extra"].get("kind", "")), level="WARNING")
    yield kinds
    logger.remove(sink)
