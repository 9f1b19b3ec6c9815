"""A second recorder on an FDR path this process already writes is refused naming this process
(a recorder, or a composed root, still open) and what to do, not "another process"."""

from __future__ import annotations

import os

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder
from c3_matcher.testing import FakeClock


def test_a_second_recorder_in_this_process_is_told_this_process_writes_it(tmp_path) -> None:
    path = tmp_path / "fdr.jsonl"
    first = JsonlFdrRecorder(path, FakeClock())
    try:
        with pytest.raises(FdrOpenError) as info:
            JsonlFdrRecorder(path, FakeClock())
        said = str(info.value)
        assert f"this process (pid {os.getpid()}) already writes this FDR" in said
        assert "close it first, or give another path" in said
        assert not said.split(": ", 1)[1].startswith("another process")
    finally:
        first.close()
    JsonlFdrRecorder(path, FakeClock()).close()  # once closed, the path is free again
