"""Ctrl-C and SIGTERM end any command with one line and the status a shell reports for the
signal (130, 143), from its very first step (the plugins' discovery) to its last; SIGTERM's
own handler is put back afterwards."""

from __future__ import annotations

import os
import signal
import time

import pytest

import c3_matcher.compose


def _start_up_then(stop: object, monkeypatch: pytest.MonkeyPatch) -> None:
    def discovery() -> None:
        if stop == "SIGTERM":
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises before this ends
        raise KeyboardInterrupt

    monkeypatch.setattr(c3_matcher.compose, "build_plugin_host", discovery)


@pytest.mark.parametrize(
    ("stop", "status", "line"),
    [("Ctrl-C", 130, "c3-matcher: interrupted"), ("SIGTERM", 143, "c3-matcher: terminated")],
)
def test_a_stop_during_start_up_is_one_line_and_the_signals_status(
    stop: str,
    status: int,
    line: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main

    before = signal.getsignal(signal.SIGTERM)
    _start_up_then(stop, monkeypatch)
    started = time.monotonic()
    assert main(["plugins"]) == status
    assert time.monotonic() - started < 4
    assert capsys.readouterr().err == line + "\n"
    assert signal.getsignal(signal.SIGTERM) is before
