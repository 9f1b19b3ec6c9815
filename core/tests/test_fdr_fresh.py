"""A recorder that starts a new log at its path (``fresh=True``, a ground run's FDR): the
previous log (live and rotated segments, ``.meta``, ``.torn``) is removed only once the lock is
held, so a recorder the lock refuses leaves another writer's files as they are; and no recorder,
fresh or not, touches a path that holds something other than a log of records."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, read_fdr
from c3_matcher.testing import FakeClock

REAL_PNG = (Path(__file__).resolve().parents[2] / "data" / "demo" / "tile_a.png").read_bytes()


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
        with pytest.raises(FdrOpenError, match="already writes this FDR"):  # (this process)
            JsonlFdrRecorder(path, FakeClock(), max_bytes=1024, fresh=True)
        assert _files(tmp_path) == before
    finally:
        writer.close()


@pytest.mark.parametrize("fresh", [False, True])
def test_a_path_holding_another_file_is_refused_and_left_as_it_was(
    tmp_path: Path, fresh: bool
) -> None:
    """An image given as the FDR path by mistake: its bytes stay, and nothing is made beside it
    (the recorder used to cut its tail as a torn line and append records to it)."""
    image = tmp_path / "tile.png"
    image.write_bytes(REAL_PNG)
    with pytest.raises(FdrOpenError, match="something other than flight-data records"):
        JsonlFdrRecorder(image, FakeClock(), fresh=fresh)
    assert image.read_bytes() == REAL_PNG
    assert [p.name for p in tmp_path.iterdir()] == ["tile.png"]


def test_a_log_whose_only_line_is_torn_is_still_a_log(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    path.write_bytes(b'{"seq": 1, "kind": "matcher.fra')  # power cut in the first record
    recorder = JsonlFdrRecorder(path, FakeClock())
    recorder.close()
    assert [r["kind"] for r in read_fdr(path)] == ["fdr.torn_tail_cut"]
