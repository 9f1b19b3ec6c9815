"""The durable FDR recorder: fsync before return, size rotation, SIGKILL survival."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.dto import TileId
from c3_matcher.fdr import FdrWriteError, InMemoryFdr, JsonlFdrRecorder, read_fdr
from c3_matcher.testing import FakeClock

CORE_SRC = Path(__file__).resolve().parents[1] / "src"


def test_records_are_json_lines_with_schema(tmp_path):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    fid = uuid.uuid4()
    rec.record(
        "matcher.frame_done",
        {"frame_id": fid, "best_tile_id": TileId(18, 1.0, 2.0), "h": np.eye(3), "n": np.int64(3)},
    )
    rec.record("log.error", {"message": "x"})
    rows = list(read_fdr(rec.path))
    assert [r["seq"] for r in rows] == [1, 2]
    assert rows[0]["kind"] == "matcher.frame_done"
    assert rows[0]["payload"] == {
        "frame_id": str(fid),
        "best_tile_id": [18, 1.0, 2.0],
        "h": np.eye(3).tolist(),
        "n": 3,
    }
    rec.close()
    again = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())  # sequence continues
    again.record("x", {})
    assert [r["seq"] for r in read_fdr(again.path)] == [1, 2, 3]


def test_rotation_keeps_every_record(tmp_path):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock(), max_bytes=2048)
    for i in range(100):
        rec.record("k", {"i": i, "pad": "x" * 40})
    segments = rec.segments()
    assert len(segments) > 3
    assert all(p.stat().st_size <= 2048 for p in segments)
    seen = [r["payload"]["i"] for p in segments for r in read_fdr(p)]
    assert seen == list(range(100))


def test_write_failure_keeps_the_record_pending(tmp_path, monkeypatch):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    real_write = os.write
    monkeypatch.setattr(os, "write", lambda fd, data: (_ for _ in ()).throw(OSError("ENOSPC")))
    with pytest.raises(FdrWriteError, match="1 record"):
        rec.record("k", {"i": 0})
    monkeypatch.setattr(os, "write", real_write)
    rec.record("k", {"i": 1})
    assert [r["payload"]["i"] for r in read_fdr(rec.path)] == [0, 1]


def test_sigkill_loses_no_acknowledged_record(tmp_path):
    path = tmp_path / "fdr.jsonl"
    acks = tmp_path / "acks.txt"
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.fdr import JsonlFdrRecorder
        from c3_matcher.health import MonotonicClock
        rec = JsonlFdrRecorder(__import__("pathlib").Path({str(path)!r}), MonotonicClock(),
                               max_bytes=4096)
        ack = open({str(acks)!r}, "w", buffering=1)
        i = 0
        while True:
            rec.record("matcher.frame_done", {{"i": i, "pad": "y" * 100}})
            ack.write(f"{{i}}\\n")  # acknowledged only after record() returned
            i += 1
    """)
    proc = subprocess.Popen([sys.executable, "-c", script])
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if acks.exists() and len(acks.read_text().splitlines()) > 200:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    acknowledged = [int(x) for x in acks.read_text().splitlines() if x.strip()]
    assert len(acknowledged) > 200
    # killed between a rotation and the next write, there is no live segment yet: fine
    segments = [*sorted(tmp_path.glob("fdr.[0-9]*.jsonl")), *([path] if path.exists() else [])]
    found = []
    for seg in segments:
        raw = seg.read_bytes()
        lines = raw.split(b"\n")
        for line in lines[:-1]:  # every complete line parses
            found.append(json.loads(line)["payload"]["i"])
    assert set(acknowledged) <= set(found)
    assert found == sorted(found)


def test_in_memory_double():
    fdr = InMemoryFdr()
    fdr.record("a", {"x": np.float32(1.5)})
    assert fdr.of_kind("a") == [{"x": 1.5}]
