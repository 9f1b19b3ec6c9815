"""Structured logging: JSON on the stream, every record with a kind, ERROR/WARN to the FDR."""

from __future__ import annotations

import io
import json
import os

import pytest

from c3_matcher.fdr import InMemoryFdr, JsonlFdrRecorder, read_fdr
from c3_matcher.logs import FDR_WRITE_FAILED, configure_logging, log_event
from c3_matcher.testing import FakeClock


def test_json_records_with_kind_and_fields():
    stream = io.StringIO()
    fdr = InMemoryFdr()
    handle = configure_logging(fdr, level="INFO", stream=stream)
    try:
        log_event("INFO", "c3.matcher.ready", "C3 ready: matcher=x", strategy="x")
        log_event("DEBUG", "c3.matcher.candidates", "hidden at INFO")
        log_event("WARNING", "c3.matcher.residual_above_threshold", "w", residual_px=4.2)
        log_event("ERROR", "c3.matcher.insufficient_inliers", "e", best_inlier_count=3)
    finally:
        handle.close()
    lines = [json.loads(x) for x in stream.getvalue().splitlines()]
    assert [(r["level"], r["kind"]) for r in lines] == [
        ("INFO", "c3.matcher.ready"),
        ("WARNING", "c3.matcher.residual_above_threshold"),
        ("ERROR", "c3.matcher.insufficient_inliers"),
    ]
    assert lines[0]["strategy"] == "x" and lines[1]["residual_px"] == 4.2
    assert [k for k, _ in fdr.records] == ["log.warning", "log.error"]
    assert fdr.records[1][1]["kind"] == "c3.matcher.insufficient_inliers"


def test_failing_fdr_does_not_loop_or_raise():
    class Broken:
        calls = 0

        def record(self, kind, payload):  # type: ignore[no-untyped-def]
            Broken.calls += 1
            raise OSError("disk full")

    stream = io.StringIO()
    handle = configure_logging(Broken(), stream=stream)
    try:
        log_event("ERROR", "c3.test", "boom")
    finally:
        handle.close()
    assert Broken.calls == 1
    assert json.loads(stream.getvalue().splitlines()[0])["kind"] == "c3.test"


def test_a_full_disk_keeps_forwards_pending_says_nothing_on_stderr_and_no_more_about_itself(
    tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every stderr line stays JSON while the disk is full (loguru would print a traceback for a
    sink that raises), and the FDR's own write failures are not queued into it: one more pending
    record per failure, for as long as the disk stays full."""
    real_write = os.write

    def full(fd: int, data: bytes) -> int:
        raise OSError(28, "No space left on device")

    recorder = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    stream = io.StringIO()
    handle = configure_logging(recorder, stream=stream)
    try:
        monkeypatch.setattr(os, "write", full)
        log_event("WARNING", "c3.matcher.residual_above_threshold", "w", residual_px=4.2)
        log_event("ERROR", FDR_WRITE_FAILED, "FDR write failed for matcher.frame_done")
        assert recorder.pending == 1  # the warning, kept for when space returns
        monkeypatch.setattr(os, "write", real_write)
        recorder.flush()
    finally:
        handle.close()
        recorder.close()
    assert capsys.readouterr().err == ""
    kinds = [json.loads(x)["kind"] for x in stream.getvalue().splitlines()]
    assert kinds == ["c3.matcher.residual_above_threshold", FDR_WRITE_FAILED]
    landed = list(read_fdr(tmp_path / "fdr.jsonl"))
    assert [(r["kind"], r["payload"]["kind"]) for r in landed] == [
        ("log.warning", "c3.matcher.residual_above_threshold")
    ]


def test_a_log_stream_that_cannot_be_written_drops_and_counts_its_lines(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """The JSON log's own disk full (replay's matcher.log, stderr on a full log disk): each line
    it cannot take is dropped and counted, with no traceback from loguru and nothing raised."""

    class FullDisk(io.StringIO):
        def write(self, s: str) -> int:
            raise OSError(28, "No space left on device")

    handle = configure_logging(None, stream=FullDisk())
    try:
        for n in range(3):
            log_event("WARNING", "c3.matcher.residual_above_threshold", "w", residual_px=float(n))
    finally:
        handle.close()
    assert handle.lines_lost == 3
    assert capfd.readouterr().err == ""


def test_an_embedding_programs_own_sink_survives_configure_and_close() -> None:
    import io

    from loguru import logger

    from c3_matcher.logs import configure_logging, log_event

    mine = io.StringIO()
    sink = logger.add(mine, format="{message}")
    try:
        handle = configure_logging(None, stream=io.StringIO())
        log_event("INFO", "t.during", "during")
        handle.close()
        log_event("INFO", "t.after", "after")
        assert "during" in mine.getvalue() and "after" in mine.getvalue()
    finally:
        logger.remove(sink)
