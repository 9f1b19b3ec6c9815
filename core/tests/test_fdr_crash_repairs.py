"""What the recorder leaves after faults at awkward moments, and what the next write or the next
recorder makes of it: a kill right after a rotation, a written line whose fsync and rollback
both fail, a live segment a power cut left as NUL bytes. Each time the log must stay whole:
every acknowledged record once, ``seq`` without a gap no note explains."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, FdrWriteError, JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.testing import FakeClock

CORE_SRC = Path(__file__).resolve().parents[1] / "src"


def test_a_kill_in_the_first_write_after_a_rotation_leaves_no_unexplained_gap(
    tmp_path: Path,
) -> None:
    """``.meta`` is written at a rotation; it used to count the record being written as given,
    so the next recorder went on one seq above a record that never reached the log."""
    path = tmp_path / "fdr.jsonl"
    script = textwrap.dedent(f"""
        import os, sys
        from pathlib import Path
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.fdr import JsonlFdrRecorder
        from c3_matcher.testing import FakeClock
        rec = JsonlFdrRecorder(Path({str(path)!r}), FakeClock(), max_bytes=1024)
        rename = Path.rename
        def rename_then_lose_power(self, target):
            out = rename(self, target)
            os.write = lambda fd, data: os._exit(9)  # nothing after the rename reaches the disk
            return out
        Path.rename = rename_then_lose_power
        for i in range(100):
            rec.record("k", {{"i": i, "pad": "x" * 200}})
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 9, out.stderr
    meta = json.loads(path.with_name("fdr.jsonl.meta").read_text())
    acknowledged = [r["seq"] for r in read_fdr_log(path)]
    assert meta["last_seq"] == acknowledged[-1]  # the record in flight was never acknowledged
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    again.record("k", {"after": "restart"})
    again.close()
    assert [r["seq"] for r in read_fdr_log(path)] == [*acknowledged, acknowledged[-1] + 1]
    check = check_fdr(path)
    assert check.intact and not check.noted_gaps


def _failing(real, fails: dict[str, int], name: str):
    """``real`` that raises EIO the first ``fails[name]`` times it is called."""

    def call(*args):
        if fails[name]:
            fails[name] -= 1
            raise OSError(errno.EIO, "I/O error (injected)")
        return real(*args)

    return call


@pytest.mark.parametrize("written", ["whole", "half"])
def test_a_line_whose_fsync_and_rollback_failed_is_cut_not_written_twice(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, written: str
) -> None:
    """The write lands (whole, or half and then the disk refuses the rest), fsync fails and so
    does the ftruncate that would roll it back: the next write cuts the segment back to where
    that record began, so the record, still pending, is in the log once."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    fails = {"fsync": 1 if written == "whole" else 0, "ftruncate": 1}
    real_write = os.write
    if written == "half":
        calls = []

        def half_then_refuse(fd: int, data: bytes) -> int:
            calls.append(fd)
            if len(calls) == 1:
                return real_write(fd, bytes(data[: len(data) // 2]))
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(os, "write", half_then_refuse)
    monkeypatch.setattr(os, "fsync", _failing(os.fsync, fails, "fsync"))
    monkeypatch.setattr(os, "ftruncate", _failing(os.ftruncate, fails, "ftruncate"))
    with pytest.raises(FdrWriteError, match="1 record"):
        rec.record("k", {"i": 1})
    monkeypatch.undo()
    rec.record("k", {"i": 2})
    rec.close()
    assert [(r["seq"], r["payload"]) for r in read_fdr_log(path)] == [
        (1, {"i": 0}),
        (2, {"i": 1}),
        (3, {"i": 2}),
    ]
    assert check_fdr(path).intact
    (cut,) = [json.loads(line) for line in rec.torn_path.read_text().splitlines()]
    assert cut["bytes"].startswith('{"seq":2,') and cut["offset"] == len(
        path.read_bytes().splitlines(keepends=True)[0]
    )


def test_a_live_segment_left_as_nul_bytes_is_cut_as_a_torn_tail(tmp_path: Path) -> None:
    """A power cut during a segment's first line, on a file system that had committed the new
    size but not the data (XFS, FAT): the file reads as NUL bytes. The recorder opens, cuts them
    into ``.torn`` and goes on; it used to refuse the path as holding something else."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    rec.close()
    path.rename(tmp_path / "fdr.000001.jsonl")  # as a rotation leaves it
    path.write_bytes(b"\0" * 180)
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("k", {"i": 1})
    again.close()
    records = list(read_fdr_log(path))
    assert [(r["seq"], r["kind"]) for r in records] == [
        (1, "k"),
        (2, "fdr.torn_tail_cut"),
        (3, "k"),
    ]
    assert records[1]["payload"]["offset"] == 0 and records[1]["payload"]["length"] == 180
    assert check_fdr(path).intact


def test_a_first_segment_of_nul_bytes_is_a_log_and_a_file_beginning_with_nul_is_not(
    tmp_path: Path,
) -> None:
    """Only a file of NUL bytes alone is a torn line: a format that begins with NUL bytes (an
    MP4, an icon) is refused, and never cut or appended to."""
    torn = tmp_path / "fdr.jsonl"
    torn.write_bytes(b"\0" * 70_000)  # more than one block read
    JsonlFdrRecorder(torn, FakeClock()).close()
    assert [r["kind"] for r in read_fdr_log(torn)] == ["fdr.torn_tail_cut"]
    video = tmp_path / "clip.mp4"
    data = b"\0" * 70_000 + b"\0\0\0\x18ftypmp42" + bytes(range(256))
    video.write_bytes(data)
    with pytest.raises(FdrOpenError, match="something other than flight-data records"):
        JsonlFdrRecorder(video, FakeClock())
    assert video.read_bytes() == data
