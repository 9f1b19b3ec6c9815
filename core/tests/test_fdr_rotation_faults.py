"""Rotations the file system gets in the way of: a live segment it refuses to grow (EFBIG, a
file-size limit below ``max_bytes``) and a rotation that fails (said once per outage)."""

from __future__ import annotations

import errno
import io
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.fdr.rotation import ROTATE_FAILED
from c3_matcher.logs import configure_logging
from c3_matcher.testing import FakeClock

CORE_SRC = Path(__file__).resolve().parents[1] / "src"
FILE_LIMIT = 200 * 1024  # RLIMIT_FSIZE in the child: far below its max_bytes

# A real file-size limit (RLIMIT_FSIZE), set in a child process only. Past it a write fails
# with EFBIG and the kernel sends SIGXFSZ, which kills by default: ignored here, as Python
# itself ignores it at start-up, so that the write's error is what the recorder sees.
_LIMITED_SCRIPT = """
import json, resource, signal, sys
from pathlib import Path
sys.path.insert(0, {src!r})
from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder
from c3_matcher.testing import FakeClock
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
rec = JsonlFdrRecorder(Path({path!r}), FakeClock(), max_bytes=1024 * 1024,
                       max_pending_bytes=64 * 1024)
failed = []
for i in range(600):
    try:
        rec.record("k", {{"i": i, "pad": "a" * 1300}})
    except FdrWriteError:
        failed.append(i)
print(json.dumps({{"failed": failed, "pending": rec.pending, "let_go": rec.dropped}}))
rec.close()
"""


def test_a_file_size_limit_below_max_bytes_rotates_and_loses_nothing(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    script = _LIMITED_SCRIPT.format(src=str(CORE_SRC), limit=FILE_LIMIT, path=str(path))
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.stdout, proc.stderr[-3000:]
    report = json.loads(proc.stdout.splitlines()[-1])
    assert report == {"failed": [], "pending": 0, "let_go": 0}
    assert proc.returncode == 0, proc.stderr[-3000:]  # its close lost nothing either
    check = check_fdr(path)
    assert check.intact and check.records == 600 and check.let_go == 0
    assert [r["payload"]["i"] for r in read_fdr_log(path)] == list(range(600))
    assert len(check.segments) >= 4  # 600 records of 1.3 kB: about 4 limits' worth
    assert all(s.stat().st_size <= FILE_LIMIT for s in check.segments)


def test_a_write_still_too_large_after_its_rotation_is_kept_pending(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One rotation, one retry: then a record waits, as on a full disk, and later ones make no
    empty segments."""
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    rec.record("k", {"i": 0})
    real_write = os.write

    def too_large(fd: int, data: bytes) -> int:
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(os, "write", too_large)
    for i in (1, 2):
        with pytest.raises(FdrWriteError, match="File too large"):
            rec.record("k", {"i": i})
    assert rec.pending == 2 and len(rec.segments()) == 2  # the one rotation, before the retry
    monkeypatch.setattr(os, "write", real_write)
    rec.record("k", {"i": 3})
    assert [r["payload"]["i"] for r in read_fdr_log(rec.path)] == [0, 1, 2, 3]
    rec.close()


def _rotate_failed(stream: io.StringIO) -> list[dict]:
    lines = [json.loads(line) for line in stream.getvalue().splitlines() if line]
    return [r for r in lines if r["kind"] == ROTATE_FAILED]


def test_a_failed_rotation_is_said_once_per_outage(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The directory refuses the rename: one WARNING over many records (forwarded into this
    very recorder, as the composed logs do), and one again once a rotation has succeeded and
    the next fails."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    stream = io.StringIO()
    handle = configure_logging(rec, level="DEBUG", stream=stream)
    real_rename = Path.rename

    def refuse(self: Path, target: Path) -> Path:
        raise PermissionError(errno.EACCES, "Permission denied", str(self))

    try:
        for i in range(12):
            rec.record("k", {"i": i, "pad": "x" * 60})
        monkeypatch.setattr(Path, "rename", refuse)
        for i in range(12, 40):  # a rotation is due and fails at each
            rec.record("k", {"i": i, "pad": "x" * 60})
        said = _rotate_failed(stream)
        assert len(said) == 1 and said[0]["level"] == "WARNING"
        assert said[0]["segment"] == str(path) and 0 < said[0]["size"] <= 1024  # when it was due
        assert "PermissionError" in said[0]["error"] and "Permission denied" in said[0]["error"]
        monkeypatch.setattr(Path, "rename", real_rename)
        rec.record("k", {"i": 40})  # rotates
        monkeypatch.setattr(Path, "rename", refuse)
        for i in range(41, 70):
            rec.record("k", {"i": i, "pad": "x" * 60})
        assert len(_rotate_failed(stream)) == 2
    finally:
        handle.close()
        rec.close()
    forwarded = [r for r in read_fdr_log(path) if r["kind"] == "log.warning"]
    assert [r["payload"]["kind"] for r in forwarded] == [ROTATE_FAILED] * 2
    assert check_fdr(path).intact
