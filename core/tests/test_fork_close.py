"""A worker forked from a process whose other threads were busy (one matching frames, one
writing the flight data recorder, one reading a tile) closes what it inherited at once: the
matcher, its recorder, the tile store. A lock it inherited may be held by a thread that does not
exist in it, so closing there waits for no lock, and writes, truncates and unlocks nothing of the
parent's: the parent's frame finishes, its log goes on whole under its own lock, its store serves
tiles. Real ``os.fork`` while another thread is stopped inside the lock (never left to luck); the
child says what happened through a pipe, and one that has said nothing after ``DEADLINE_S`` hung."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher.compose import ComposedRoot, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.errors import MatcherClosedError, describe
from c3_matcher.fdr import FdrOpenError, FdrWriteError, JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.testing import (
    FakeBackend,
    FakeClock,
    ScriptedCandidate,
    fake_helpers,
    make_frame,
    make_rerank,
    one_strategy_host,
    pipeline_strategy,
)
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError

from .forking import DEADLINE_S, in_forked_child

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
SCRIPT = [ScriptedCandidate(100), ScriptedCandidate(90)]
PAD = "x" * 300  # four records pass the 1024-byte segments: the parent's log rotates


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)


class _Stop:
    """Where a parent thread stops (``reached``), holding what it holds there, until ``go``."""

    def __init__(self) -> None:
        self.armed = threading.Event()
        self.reached = threading.Event()
        self.go = threading.Event()

    def here(self) -> None:
        """Stop the first caller once ``armed``."""
        if self.armed.is_set() and not self.reached.is_set():
            self.reached.set()
            self.go.wait()


class _StoppingClock(FakeClock):
    """A clock that stops its first reader once armed: a recorder reads it inside its lock as it
    makes each record, so the thread stopped there holds the recorder's lock."""

    def __init__(self, stop: _Stop) -> None:
        super().__init__()
        self._stop = stop

    def monotonic_ns(self) -> int:
        self._stop.here()
        return super().monotonic_ns()


def _in_forked_child(work: Callable[[], str]) -> str:
    """What ``work`` returned in a forked child (:func:`.forking.in_forked_child`)."""
    return in_forked_child(work)[1]


def _forked_while_stopped(
    stop: _Stop, busy: Callable[[], None], in_child: Callable[[], str]
) -> str:
    """Run ``busy`` on a parent thread; once it has stopped at ``stop``, fork and run
    ``in_child`` in the child; then let the thread go on and see it finish. What the child said."""
    failures: list[BaseException] = []

    def run() -> None:
        try:
            busy()
        except BaseException as exc:
            failures.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    stop.armed.set()
    thread.start()
    try:
        assert stop.reached.wait(DEADLINE_S), "the parent thread never reached its stop"
        said = _in_forked_child(in_child)
    finally:
        stop.go.set()
        thread.join(DEADLINE_S)
    assert not thread.is_alive()
    assert failures == []
    return said


def _root(path: Path, **helpers: Any) -> ComposedRoot:
    host = one_strategy_host("fake", pipeline_strategy(FakeBackend))
    settings = C3Settings(matcher={"strategy": "fake"}, fdr={"path": path, "max_bytes": 1024})
    return compose_root(settings, {**fake_helpers(SCRIPT), **helpers}, plugin_host=host)


def _match(root: ComposedRoot) -> Any:
    frame, calibration = make_frame()
    return root.matcher.match(frame, make_rerank(frame.frame_id, SCRIPT), calibration)


def _refused_match(root: ComposedRoot) -> str:
    try:
        _match(root)
    except MatcherClosedError as exc:
        return describe(exc)
    return "matched"


def _assert_intact(path: Path, kinds: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """The log at ``path`` holds records of ``kinds``, seq 1.. in order, over several segments,
    and ``c3-matcher fdr`` says it is intact."""
    records = list(read_fdr_log(path))
    assert [r["kind"] for r in records] == kinds
    assert [r["seq"] for r in records] == list(range(1, len(kinds) + 1))
    assert len(check_fdr(path).segments) > 1
    capsys.readouterr()
    assert main(["fdr", str(path)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == f"{path}: intact"


def _assert_lock_kept(path: Path) -> None:
    """The parent still holds the log's lock: a second recorder is refused, naming it."""
    with pytest.raises(FdrOpenError, match=f"pid {os.getpid()}"):
        JsonlFdrRecorder(path, FakeClock())


def test_a_forked_child_closes_a_recorder_another_thread_was_writing(tmp_path, capsys) -> None:
    path = tmp_path / "fdr.jsonl"
    stop = _Stop()
    recorder = JsonlFdrRecorder(path, _StoppingClock(stop), max_bytes=1024)
    recorder.record("test.before", {"pad": PAD})

    def child_closes() -> str:
        recorder.close()  # its lock is held by the writing thread, which the child lacks
        recorder.close()
        try:
            recorder.record("test.child", {"pad": PAD})
        except FdrWriteError as exc:
            return f"closed; {describe(exc)}"
        return "written"

    said = _forked_while_stopped(
        stop, lambda: recorder.record("test.stopped", {"pad": PAD}), child_closes
    )
    assert said.startswith(f"closed; FdrWriteError: FDR {path}: not written, made in process ")
    for _ in range(3):  # the parent goes on, across rotations, under its own lock
        recorder.record("test.after", {"pad": PAD})
    _assert_lock_kept(path)
    recorder.close()
    _assert_intact(path, ["test.before", "test.stopped", *["test.after"] * 3], capsys)


def test_a_forked_child_closes_a_matcher_whose_frame_was_in_progress(tmp_path, capsys) -> None:
    path = tmp_path / "fdr.jsonl"
    stop = _Stop()  # the first frame stops as it records: its turn and the recorder's lock held
    recorder = JsonlFdrRecorder(path, _StoppingClock(stop), max_bytes=1024)
    root = _root(tmp_path / "unused.jsonl", c13_fdr=recorder)
    matched: list[int] = []

    def matching() -> None:
        while len(matched) < 3:
            matched.append(_match(root).per_candidate[0].inlier_count)

    def child_closes() -> str:
        root.close()  # the matcher and the log sinks
        recorder.close()  # the recorder the caller gave
        return f"closed; {_refused_match(root)}"

    said = _forked_while_stopped(stop, matching, child_closes)
    assert said.startswith("closed; MatcherClosedError: matcher 'fake' cannot match here: ")
    assert matched == [100, 100, 100]  # the parent's frame finished, and the next ones
    assert _match(root).per_candidate[0].inlier_count == 100
    _assert_lock_kept(path)
    root.close()
    recorder.close()
    _assert_intact(path, ["matcher.frame_done"] * 4, capsys)


def test_a_forked_child_closes_a_root_whose_recorder_another_thread_was_writing(
    tmp_path, capsys
) -> None:
    path = tmp_path / "fdr.jsonl"
    stop = _Stop()
    root = _root(path, clock=_StoppingClock(stop))  # its own recorder, on the root's clock
    assert _match(root).per_candidate[0].inlier_count == 100

    def child_closes() -> str:
        root.close()  # the matcher, the log sinks and the recorder the root made
        return f"closed; {_refused_match(root)}"

    said = _forked_while_stopped(  # another part of the system writing the same FDR
        stop, lambda: root.fdr.record("test.stopped", {"pad": PAD}), child_closes
    )
    assert said.startswith("closed; MatcherClosedError: matcher 'fake' cannot match here: ")
    assert _match(root).per_candidate[0].inlier_count == 100
    _assert_lock_kept(path)
    root.close()
    _assert_intact(path, ["matcher.frame_done", "test.stopped", "matcher.frame_done"], capsys)


def _a_tile(store: MBTilesStore) -> tuple[int, int, int]:
    zoom = store.zooms()[-1]
    return (zoom, *next(iter(store.tiles(zoom))))


def test_a_forked_child_closes_a_tile_store_another_thread_was_reading() -> None:
    store = MBTilesStore(STORE)
    tile = _a_tile(store)
    expected = store.tile_bytes(*tile)
    stop = _Stop()

    def reading() -> None:  # stopped inside SQLite, mid-statement: its connection's mutex held
        store._db.set_trace_callback(lambda _statement: stop.here())
        assert store.tile_bytes(*tile) == expected

    def child_closes() -> str:
        store.close()
        store.close()
        try:
            store.tile_bytes(*tile)
        except TileStoreUnusableError as exc:
            return f"closed; {describe(exc)}; sidecar: {store.feature_store()}"
        return "read"

    said = _forked_while_stopped(stop, reading, child_closes)
    assert said.startswith("closed; TileStoreUnusableError: ")
    assert "the store is closed" in said and said.endswith("sidecar: None")
    assert store.tile_bytes(*tile) == expected  # the parent's store goes on
    store.close()


def test_a_forked_child_closes_a_tile_store_whose_connections_another_thread_held() -> None:
    store = MBTilesStore(STORE)
    tile = _a_tile(store)
    expected = store.tile_bytes(*tile)
    stop = _Stop()

    def holding() -> None:  # as a thread making its connection does
        with store._conn_lock:
            stop.here()

    def child_closes() -> str:
        store.close()
        return f"closed; sidecar: {store.feature_store()}"

    assert _forked_while_stopped(stop, holding, child_closes) == "closed; sidecar: None"
    assert store.tile_bytes(*tile) == expected
    store.close()


def test_a_forked_child_closes_a_root_while_another_thread_was_composing_one(tmp_path) -> None:
    """A parent thread composing or closing another root holds the log roots' lock for a
    moment; a child forked then closed its inherited root waiting for that lock forever."""
    from c3_matcher import logs

    root = _root(tmp_path / "fdr.jsonl")
    stop = _Stop()

    def composing() -> None:
        with logs._roots._lock:  # where a thread joining or leaving the roots is
            stop.here()

    def close_inherited() -> str:
        root.close()
        return "closed"

    try:
        assert _forked_while_stopped(stop, composing, close_inherited) == "closed"
        assert _match(root).best_candidate_idx == 0  # the parent's root goes on
    finally:
        root.close()
