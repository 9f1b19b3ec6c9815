"""A matcher composed in one process and copied into a forked child (a supervisor that composes,
then forks its workers) cannot write that process's flight data recorder: in the child, ``match``
is refused with ``MatcherClosedError`` and the inherited recorder refuses every write, each
naming both processes and saying to compose the matcher after the fork. The parent's log stays
its own: ``seq`` keeps growing across rotations, its lock stays held, ``c3-matcher fdr`` says it
is intact. Real ``os.fork``; the child says what happened through a pipe."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher.compose import ComposedRoot, compose_root
from c3_matcher.config import C3Settings
from c3_matcher.errors import MatcherClosedError, describe
from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, check_fdr, read_fdr_log
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

from .forking import in_forked_child

SCRIPT = [ScriptedCandidate(100), ScriptedCandidate(90)]


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)


def _root(path: Path) -> ComposedRoot:
    host = one_strategy_host("fake", pipeline_strategy(FakeBackend))
    settings = C3Settings(matcher={"strategy": "fake"}, fdr={"path": path, "max_bytes": 1024})
    return compose_root(settings, fake_helpers(SCRIPT), plugin_host=host, configure_logs=False)


def _match(root: ComposedRoot) -> Any:
    frame, calibration = make_frame()
    return root.matcher.match(frame, make_rerank(frame.frame_id, SCRIPT), calibration)


def _assert_intact(path: Path, records: int, capsys: pytest.CaptureFixture[str]) -> None:
    """The log at ``path`` holds ``records`` records, seq 1.. in order, and is said intact."""
    assert [r["seq"] for r in read_fdr_log(path)] == list(range(1, records + 1))
    assert check_fdr(path).intact
    capsys.readouterr()
    assert main(["fdr", str(path)]) == 0
    assert capsys.readouterr().out.splitlines()[0] == f"{path}: intact"


def _names_both_processes(said: str, child: int) -> None:
    assert f"process {os.getpid()}" in said and f"process {child}" in said
    assert "compose the matcher in the process that uses it, after the fork" in said


def test_a_forked_copy_of_a_matcher_is_refused_and_the_parents_log_stays_whole(tmp_path, capsys):
    path = tmp_path / "fdr.jsonl"
    root = _root(path)
    assert _match(root).per_candidate[0].inlier_count == 100

    def child_matches() -> str:
        try:
            _match(root)
        except MatcherClosedError as exc:  # no fix from this call: the copy's health says so
            return f"{describe(exc)} (health updates: {root.health_window.update_count})"
        finally:
            root.close()  # the copy's: the parent's frames, lock and log go on
        return "matched"

    child, said = in_forked_child(child_matches)
    assert said.startswith("MatcherClosedError: matcher 'fake' cannot match here: ")
    assert said.endswith("(health updates: 2)")
    _names_both_processes(said, child)
    for _ in range(3):  # the parent goes on, across rotations
        assert _match(root).per_candidate[0].inlier_count == 100
    root.close()
    assert len(check_fdr(path).segments) > 1
    assert [r["kind"] for r in read_fdr_log(path)] == ["matcher.frame_done"] * 4
    _assert_intact(path, 4, capsys)


def test_a_recorder_refuses_writes_from_a_forked_child_and_keeps_its_lock(tmp_path, capsys):
    path = tmp_path / "fdr.jsonl"
    recorder = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    recorder.record("matcher.frame_done", {"pad": "x" * 300})

    def child_writes() -> str:
        try:
            recorder.record("matcher.frame_done", {"pad": "y" * 300})
        finally:
            recorder.close()  # the copy's descriptors go; the parent's lock and log stay
        return "written"

    child, said = in_forked_child(child_writes)
    assert said.startswith(f"FdrWriteError: FDR {path}: ")
    _names_both_processes(said, child)
    for _ in range(5):  # seq goes on from the parent's own, across rotations
        recorder.record("matcher.frame_done", {"pad": "z" * 300})
    with pytest.raises(FdrOpenError, match=f"pid {os.getpid()}"):
        JsonlFdrRecorder(path, FakeClock())  # the lock is still the parent's
    recorder.close()
    assert len(check_fdr(path).segments) > 2
    assert all("y" not in r["payload"]["pad"] for r in read_fdr_log(path))
    _assert_intact(path, 6, capsys)
