"""``match`` whose flight-data records cannot be written (a full disk) prints its result, says
the records were lost, and exits 2, as it does for an FDR it cannot open (it exited 1: the
recorder's close raised out of the command)."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.fdr import JsonlFdrRecorder

from .demo_match import DEMO_MATCH


def test_records_lost_to_a_full_disk_are_said_after_the_result_and_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)

    def full(self: JsonlFdrRecorder, data: bytes) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(JsonlFdrRecorder, "_write_durably", full)
    assert main([*DEMO_MATCH, "--fdr", str(tmp_path / "f.jsonl")]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out)["per_candidate"]  # the result was printed
    said = [line for line in captured.err.splitlines() if line.startswith("c3-matcher: ")]
    assert len(said) == 1, captured.err
    assert "No space left on device" in said[0] and "pending" in said[0], said
    assert said[0].endswith("; the result was printed but NOT recorded in the FDR"), said
