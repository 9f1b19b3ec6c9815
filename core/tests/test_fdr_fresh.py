"""A recorder that starts a new log at its path (``fresh=True``, a ground run's FDR): the
previous log (live and rotated segments, ``.meta``, ``.torn``) is removed only once the lock is
held, so a recorder the lock refuses leaves another writer's files as they are."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, read_fdr
from c3_matcher.testing import FakeClock


def _previous_log(path: Path) -> JsonlFdrRecorder:
    """A log with rotated segments, ``.meta`` and a torn tail cut into ``.torn``, left open."""
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("k", {"i": i, "pad": "x" * 40})
    rec.close()
    with path.open("ab") as fh:
        fh.write(b'{"seq":41,"kind":"k","pay')
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    assert len(rec.segments()) > 2 and rec.torn_path.exists()
    assert path.with_name(path.name + ".meta").exists()
    return rec


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())}


def test_a_fresh_recorder_starts_a_new_log_without_the_previous_files(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    _previous_log(path).close()
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024, fresh=True)
    rec.record("k", {"i": "new"})
    assert rec.segments() == [path]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fdr.jsonl", "fdr.jsonl.lock"]
    assert [(r["seq"], r["payload"]) for r in read_fdr(path)] == [(1, {"i": "new"})]
    rec.close()


def test_a_fresh_recorder_refused_by_the_lock_removes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    writer = _previous_log(path)  # another run, still writing
    try:
        before = _files(tmp_path)
        with pytest.raises(FdrOpenError, match="another process"):
            JsonlFdrRecorder(path, FakeClock(), max_bytes=1024, fresh=True)
        assert _files(tmp_path) == before
    finally:
        writer.close()
