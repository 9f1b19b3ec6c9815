"""Structured logging: JSON on the stream, every record with a kind, ERROR/WARN to the FDR."""

from __future__ import annotations

import io
import json

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.logs import configure_logging, log_event


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
