"""A clock that passed the start-up check and goes bad mid-run (a call that raises, a float, a
negative number, a numpy integer) fails no frame: each frame is read once and still gets exactly
one terminal FDR record (``matcher.frame_done`` for a fix), one health update and its result,
timed from the clock's last good reading on; the outage is said once (WARNING
``c3.matcher.clock_unusable``), and every record's ``recorded_at_ns`` is an ``int``.

The real path: the shipped demo flight's frame 0 and its store windows, as the README's Python
example makes them, composed by ``compose_root`` with the OpenCV strategy (no engines) and its
own durable recorder."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from loguru import logger

from c3_matcher import (
    C3Settings,
    MatchResult,
    NavCameraFrame,
    RerankResult,
    TileId,
    build_default_helpers,
    compose_root,
    load_calibration,
)
from c3_matcher.fdr import check_fdr, read_fdr_log
from c3_matcher.tilestore import MBTilesStore

from .demo_match import FLIGHT, WINDOW, flight_frame

START_NS = 10**12


class _Clock:
    """A clock that reads well (one second a read) until ``bad`` is set: then it gives what
    ``bad`` gives."""

    def __init__(self) -> None:
        self.now_ns = START_NS
        self.bad: Callable[[], Any] | None = None

    def monotonic_ns(self) -> Any:
        if self.bad is not None:
            return self.bad()
        self.now_ns += 10**9
        return self.now_ns


def _raise() -> int:
    raise RuntimeError("time source lost")


BAD = {
    "float": lambda: 1.5e12,
    "negative": lambda: -5,
    "raises": _raise,
    "numpy": lambda: np.int64(2 * START_NS),
}


@pytest.fixture
def unusable() -> Iterator[list[dict[str, Any]]]:
    """The WARNINGs ``c3.matcher.clock_unusable`` logged meanwhile (their fields)."""
    said: list[dict[str, Any]] = []

    def keep(message: Any) -> None:
        if message.record["extra"].get("kind") == "c3.matcher.clock_unusable":
            said.append(dict(message.record["extra"]))

    sink = logger.add(keep, level="WARNING")
    yield said
    logger.remove(sink)


def _frame_and_rerank(store: MBTilesStore) -> tuple[NavCameraFrame, RerankResult]:
    """Frame 0 of the demo flight and its re-rank, as the README's example makes them."""
    frame, record = flight_frame()
    candidates = tuple(
        store.candidate(TileId(*c["tile_id"]), c["score"], size_px=WINDOW)
        for c in record["candidates"]
    )
    return frame, RerankResult(frame.frame_id, candidates)


@pytest.mark.parametrize("bad", sorted(BAD))
def test_a_clock_gone_bad_mid_run_fails_no_frame(tmp_path: Path, bad: str, unusable) -> None:
    clock = _Clock()
    path = tmp_path / "fdr.jsonl"
    settings = C3Settings(matcher={"strategy": "sift_magsac"}, fdr={"path": path})
    helpers = {**build_default_helpers(settings), "clock": clock}
    root = compose_root(settings, helpers, configure_logs=False)
    calibration = load_calibration(FLIGHT / "calibration.json")
    store = MBTilesStore(FLIGHT / "tiles.mbtiles")
    try:
        frame, rerank = _frame_and_rerank(store)
        good = root.matcher.match(frame, rerank, calibration)
        clock.bad = BAD[bad]
        results = [root.matcher.match(frame, rerank, calibration) for _ in range(2)]
    finally:
        store.close()
        root.close()
    assert all(isinstance(r, MatchResult) for r in results)
    assert [type(r.matched_at) for r in results] == [int, int]
    assert good.matched_at <= results[0].matched_at <= results[1].matched_at
    assert root.health_window.update_count == 3  # one a frame
    records = list(read_fdr_log(path))
    assert [r["kind"] for r in records if r["kind"].startswith("matcher.")] == [
        "matcher.frame_done"
    ] * 3
    assert all(type(r["recorded_at_ns"]) is int and r["recorded_at_ns"] >= 0 for r in records)
    assert check_fdr(path).intact
    if bad == "numpy":  # a numpy integer is a good reading: taken as its int
        assert results[0].matched_at == 2 * START_NS and unusable == []
    else:
        assert len(unusable) == 1  # once an outage, whoever read it first


def test_the_fallback_goes_on_from_the_last_good_reading() -> None:
    from c3_matcher.clocks import SteadyClock

    clock = _Clock()
    steady = SteadyClock(clock)
    last = steady.monotonic_ns()
    clock.bad = BAD["float"]
    instead = [steady.monotonic_ns() for _ in range(3)]
    assert all(type(t) is int for t in instead)
    assert last <= instead[0] <= instead[1] <= instead[2] < last + 60 * 10**9
    problem = steady.take_problem()
    assert problem is not None and "float" in problem.problem
    assert steady.take_problem() is None  # said once an outage
    clock.bad = None
    assert steady.monotonic_ns() == clock.now_ns  # good again: its own readings
    clock.bad = BAD["negative"]
    steady.monotonic_ns()
    assert steady.take_problem() is not None  # a new outage is said again
