"""Which files beside a live segment are its rotated segments: exactly the names the recorder
gives (``<stem>.<number, at least six digits><suffix>``), a longer number only once ``.meta``
has reserved it. A user's own ``fdr.1.jsonl`` or ``fdr.20240105.jsonl`` beside the log is
neither read as part of it nor removed by a fresh recorder."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.fdr import JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.fdr.files import rotated_segments
from c3_matcher.testing import FakeClock

USERS_OWN = ["fdr.1.jsonl", "fdr.20240105.jsonl", "fdr.0000001.jsonl", "fdr.00001.jsonl"]


def _log_of_three(path: Path) -> None:
    rec = JsonlFdrRecorder(path, FakeClock())
    for i in range(3):
        rec.record("k", {"i": i})
    rec.close()


@pytest.mark.parametrize("fresh", [False, True])
def test_a_users_copies_beside_the_log_are_not_its_segments(tmp_path: Path, fresh: bool) -> None:
    path = tmp_path / "fdr.jsonl"
    _log_of_three(path)
    for name in USERS_OWN:  # yesterday's log kept beside it, named by a number or a date
        shutil.copy(path, tmp_path / name)
    rec = JsonlFdrRecorder(path, FakeClock(), fresh=fresh)
    rec.record("k", {"i": 3})
    rec.close()
    assert rec.segments() == [path]
    check = check_fdr(path)
    assert check.intact and check.segments == (path,)
    assert [r["seq"] for r in read_fdr_log(path)] == ([1] if fresh else [1, 2, 3, 4])
    for name in USERS_OWN:  # never removed, even by a recorder that starts a new log
        assert [r["seq"] for r in read_fdr_log(tmp_path / name)] == [1, 2, 3]


def test_the_recorder_reads_back_every_name_it_writes_past_six_digits(tmp_path: Path) -> None:
    """A millionth rotation writes a seven-digit name; ``.meta`` reserved it first, so it is
    read as a segment (after the six-digit ones), unlike a user's file of that length."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(8):
        rec.record("k", {"i": i, "pad": "x" * 200})
    six = [p.name for p in rec.segments()[:-1]]
    assert six and all(len(name.split(".")[1]) == 6 for name in six)
    meta = path.with_name("fdr.jsonl.meta")
    meta.write_text(json.dumps({**json.loads(meta.read_text()), "last_segment": 999_999}))
    for i in range(8, 20):
        rec.record("k", {"i": i, "pad": "x" * 200})
    rec.close()
    rotated = rotated_segments(path)
    assert [n for n, _ in rotated[: len(six)]] == list(range(1, len(six) + 1))
    assert rotated[len(six)] == (1_000_000, tmp_path / "fdr.1000000.jsonl")
    assert [n for n, _ in rotated] == sorted(n for n, _ in rotated)
    assert [r["payload"]["i"] for r in read_fdr_log(path)] == list(range(20))
    assert check_fdr(path).intact
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)  # goes on after them
    again.record("k", {"i": 20})
    again.close()
    assert [r["seq"] for r in read_fdr_log(path)] == list(range(1, 22))
