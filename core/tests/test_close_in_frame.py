"""Closing a composed matcher while frames run: closed from within the frame's own thread (a
signal handler's clean shutdown while the flight loop is inside ``match``), the frame finishes
with its records and its log lines, and only then are the recorder and the log sinks closed;
closed from another thread, every call waiting and every later call is refused at once, and
``close()`` waits only for the frame in progress; callers waiting are served in the order they
called. Scripted doubles, composed through ``compose_root`` with the durable recorder it
builds."""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.compose import ComposedRoot, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.errors import MatcherClosedError
from c3_matcher.fdr import JsonlFdrRecorder, read_fdr
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
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

S = ScriptedCandidate
SCRIPT = [S(100), S(90), S(fail_decode=True)]  # the third is dropped: an ERROR, forwarded
WAIT_S = 10.0


class HookedBackend(FakeBackend):
    """Each extraction calls ``hook`` (when set) and, while ``gate`` is set up and not open,
    waits at it; ``frames`` names the thread of each extraction, in order."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.hook: Any = None
        self.gate: threading.Event | None = None
        self.entered = threading.Event()
        self.threads: list[str] = []

    def extract(self, image: PreparedImage) -> Features:
        self.threads.append(threading.current_thread().name)
        self.entered.set()
        if self.hook is not None:
            hook, self.hook = self.hook, None
            hook()
        if self.gate is not None:
            assert self.gate.wait(WAIT_S)
        return super().extract(image)


def _root(tmp_path: Path, *, configure_logs: bool = False) -> ComposedRoot:
    host = one_strategy_host("hooked", pipeline_strategy(HookedBackend))
    helpers = fake_helpers(SCRIPT)
    settings = C3Settings(matcher={"strategy": "hooked"}, fdr={"path": tmp_path / "fdr.jsonl"})
    root = compose_root(settings, helpers, plugin_host=host, configure_logs=configure_logs)
    backend: HookedBackend = root.matcher.backend  # type: ignore[attr-defined]
    backend.threads.clear()  # the start-up probe's extractions
    backend.entered.clear()
    return root


def _inputs() -> tuple[Any, Any, Any]:
    frame, calibration = make_frame()
    return frame, make_rerank(frame.frame_id, SCRIPT), calibration


def _kinds(tmp_path: Path) -> list[str]:
    return [r["kind"] for r in read_fdr(tmp_path / "fdr.jsonl")]


def test_a_signal_handlers_close_inside_match_lets_the_frame_finish_with_its_records(
    tmp_path, capsys
):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers run on the main thread only")
    root = _root(tmp_path, configure_logs=True)
    backend: HookedBackend = root.matcher.backend  # type: ignore[attr-defined]
    said: list[str] = []

    def on_term(signum: int, frame: Any) -> None:  # a flight process's clean shutdown
        root.close()
        said.append("root.close() returned")

    backend.hook = lambda: signal.raise_signal(signal.SIGUSR1)  # during the query's extraction
    previous = signal.signal(signal.SIGUSR1, on_term)
    try:
        result = root.matcher.match(*_inputs())
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert said == ["root.close() returned"]  # it returned inside the frame, which went on
    assert result.per_candidate[0].inlier_count == 100 and result.candidates_dropped == 1
    # the frame's records, the forward of its dropped candidate's ERROR included, are written
    assert _kinds(tmp_path) == ["log.error", "matcher.backbone_error", "matcher.frame_done"]
    lines = [json.loads(line) for line in capsys.readouterr().err.splitlines() if line]
    assert "c3.matcher.backbone_error" in [line["kind"] for line in lines]  # its log lines too
    assert root.logging is not None and root.logging.sink_ids == []  # then closed: sinks gone
    JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock()).close()  # and the FDR's lock given back
    with pytest.raises(MatcherClosedError):
        root.matcher.match(*_inputs())


def test_close_refuses_the_callers_waiting_and_later_ones_at_once(tmp_path):
    root = _root(tmp_path)
    backend: HookedBackend = root.matcher.backend  # type: ignore[attr-defined]
    backend.gate = threading.Event()
    outcomes: dict[str, Any] = {}

    def call(name: str) -> None:
        try:
            outcomes[name] = root.matcher.match(*_inputs())
        except MatcherClosedError as exc:
            outcomes[name] = exc

    first = threading.Thread(target=call, args=("first",))
    first.start()
    assert backend.entered.wait(WAIT_S)
    waiting = threading.Thread(target=call, args=("waiting",))
    waiting.start()
    waiting.join(0.3)
    assert waiting.is_alive()  # waits for the frame in progress
    closing = threading.Thread(target=root.close)
    closing.start()
    waiting.join(WAIT_S / 2)
    later = threading.Thread(target=call, args=("later",))
    later.start()
    later.join(WAIT_S / 2)
    # refused while the first frame is still in progress (its extraction waits at the gate)
    assert not waiting.is_alive() and isinstance(outcomes["waiting"], MatcherClosedError)
    assert not later.is_alive() and isinstance(outcomes["later"], MatcherClosedError)
    assert first.is_alive() and closing.is_alive()  # close() waits for that frame only
    backend.gate.set()
    first.join(WAIT_S)
    closing.join(WAIT_S)
    assert not closing.is_alive()
    assert outcomes["first"].per_candidate[0].inlier_count == 100
    assert _kinds(tmp_path)[-1] == "matcher.frame_done"
    assert _kinds(tmp_path).count("matcher.frame_done") == 1
    assert root.health_window.update_count == 3  # once per call: one fix, two refusals


def test_callers_waiting_are_served_in_the_order_they_called(tmp_path):
    root = _root(tmp_path)
    backend: HookedBackend = root.matcher.backend  # type: ignore[attr-defined]
    backend.gate = threading.Event()

    inputs = _inputs()

    def frames(count: int) -> None:
        for _ in range(count):
            root.matcher.match(*inputs)

    looping = threading.Thread(target=frames, args=(3,), name="loop")
    looping.start()
    assert backend.entered.wait(WAIT_S)
    other = threading.Thread(target=frames, args=(1,), name="other")
    other.start()
    other.join(0.3)  # now waiting for the loop's first frame
    backend.gate.set()
    looping.join(WAIT_S)
    other.join(WAIT_S)
    root.close()
    turns = [t for i, t in enumerate(backend.threads) if i == 0 or backend.threads[i - 1] != t]
    assert turns == ["loop", "other", "loop"]  # the loop's next frames came after: they waited
