"""A caller's own FDR client (``c13_fdr``) that fails a forwarded WARNING or ERROR: one JSON line
``c3.fdr.write_failed`` naming the failure, never loguru's multi-line traceback on stderr, and
no forward of that line or of the client's own logs back into the client (no recursion)."""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from typing import Any

from loguru import logger

from c3_matcher.logs import configure_logging, log_event


class BusDown:
    """An FDR client whose bus is down: every ``record`` fails with an OSError, after logging a
    WARNING of its own."""

    def __init__(self) -> None:
        self.calls: list[str] = []

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        self.calls.append(kind)
        logger.bind(kind="c3.test.bus").warning("the FDR bus is down")  # its own log line
        raise OSError(5, "Input/output error (FDR bus down)")


def _lines(stream: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stream.getvalue().splitlines() if line]


def test_a_client_failing_a_forward_is_one_json_line_without_traceback(capsys) -> None:
    client = BusDown()
    stream = io.StringIO()
    handle = configure_logging(client, level="DEBUG", stream=stream)
    try:
        log_event("WARNING", "c3.test.warning", "a warning to forward")
        log_event("ERROR", "c3.test.error", "an error to forward")
    finally:
        handle.close()
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Logging error" not in err, err
    assert client.calls == ["log.warning", "log.error"]  # once each: nothing forwarded back
    lines = _lines(stream)
    failed = [r for r in lines if r["kind"] == "c3.fdr.write_failed"]
    assert [r["record_kind"] for r in failed] == ["log.warning", "log.error"]
    assert all(r["level"] == "ERROR" and "FDR bus down" in r["error"] for r in failed)
    assert [r["kind"] for r in lines].count("c3.test.bus") == 2  # the client's own lines, said


def test_a_forward_in_one_thread_does_not_drop_another_threads() -> None:
    """The forwarder keeps out records logged during a forward on the same thread only."""
    import threading

    seen: list[str] = []
    entered, release = threading.Event(), threading.Event()

    class Slow:
        def record(self, kind: str, payload: Mapping[str, Any]) -> None:
            seen.append(payload["message"])
            if payload["message"] == "first":
                entered.set()
                assert release.wait(5)

    handle = configure_logging(Slow(), level="DEBUG", stream=io.StringIO())
    try:
        first = threading.Thread(target=log_event, args=("WARNING", "c3.test", "first"))
        first.start()
        assert entered.wait(5)
        second = threading.Thread(target=log_event, args=("WARNING", "c3.test", "second"))
        second.start()
        second.join(0.2)
        release.set()
        first.join(5)
        second.join(5)
    finally:
        handle.close()
    assert seen == ["first", "second"]
