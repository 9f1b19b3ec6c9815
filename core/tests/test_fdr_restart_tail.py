"""A recorder restarting on an existing log (the flight process back after a crash, mid-flight)
reads the log from its end, only as far back as it must: the last record's seq, and which of
the records the lock file names as lost did reach the log. What it finds equals what reading
every record of the newest rotated segment and the live one finds, on logs the recorder wrote:
rotated, with damaged lines, a torn tail, a live segment empty after a rotation, records longer
than a block; where the end of a damaged log does not rise seq by seq, it reads them whole."""

from __future__ import annotations

import json
import tracemalloc
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from c3_matcher.fdr import JsonlFdrRecorder, read_fdr, tail
from c3_matcher.fdr.files import meta_path, read_meta, rotated_segments
from c3_matcher.fdr.pending import (
    RECORDS_DROPPED,
    STOPPED,
    DroppedRecords,
    lock_path,
    lock_text,
    read_lock,
)
from c3_matcher.fdr.tail import all_seqs, tail_seqs
from c3_matcher.testing import FakeClock


def _spy_parses(m: pytest.MonkeyPatch) -> list[bytes | str]:
    """Every text ``json.loads`` is given while ``m`` holds."""
    parsed: list[bytes | str] = []
    real = json.loads

    def loads(text: bytes | str, *args: object, **kwargs: object) -> object:
        parsed.append(text)
        return real(text, *args, **kwargs)  # type: ignore[arg-type]

    m.setattr(json, "loads", loads)
    return parsed


def _recent(path: Path) -> list[Path]:
    """The segments a restart reads: the newest rotated one and the live one, as there."""
    return [p for p in [*(q for _, q in rotated_segments(path)[-1:]), path] if p.exists()]


def _full_read_seqs(path: Path) -> list[int]:
    """Every seq a restart at ``path`` counts, every record of ``_recent`` read whole."""
    seqs = [r.get("seq", 0) for p in _recent(path) for r in read_fdr(p)]
    return [s for s in seqs if isinstance(s, int)]


def _full_read_start(path: Path) -> tuple[int, DroppedRecords | None]:
    """What a restart at ``path`` must find, from every record it counts: the next seq, and
    the note of the records lost that the log lacks."""
    seqs = _full_read_seqs(path)
    carried = read_lock(lock_path(path))[1]
    meta_seq = int(read_meta(meta_path(path)).get("last_seq", 0))
    next_seq = max([meta_seq, *seqs, carried.last_seq if carried else 0]) + 1
    return next_seq, carried and carried.without(seqs)


def _restart_as_a_full_read_would(path: Path, *, whole: bool) -> None:
    """Restart a recorder at ``path`` and write a record: it goes on at the seq a full read
    finds, after the note of the records lost that the log lacks, having read the segments
    ``whole`` (``all_seqs``) or only from their end."""
    next_seq, lost = _full_read_start(path)
    read_whole: list[Sequence[Path]] = []

    def whole_read(segments: Sequence[Path]) -> list[int]:
        read_whole.append(segments)
        return all_seqs(segments)

    with pytest.MonkeyPatch.context() as m:
        m.setattr(tail, "all_seqs", whole_read)
        rec = JsonlFdrRecorder(path, FakeClock())
    assert bool(read_whole) == whole
    rec.record("probe", {})
    rec.close()
    records = [r for seg in rec.segments() if seg.exists() for r in read_fdr(seg)]
    new = [r for r in records if type(r.get("seq")) is int and r["seq"] >= next_seq]
    assert [r["seq"] for r in new] == list(range(next_seq, next_seq + len(new)))
    assert new[-1]["kind"] == "probe"
    notes = [r["payload"] for r in new if r["kind"] == RECORDS_DROPPED]
    assert notes == ([lost.payload()] if lost else [])


def _log(path: Path, n: int, *, max_bytes: int = 64 << 20, pad: int = 60) -> None:
    """``n`` records written by a recorder at ``path`` (rotated above ``max_bytes``)."""
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=max_bytes)
    for i in range(n):
        rec.record("k", {"i": i, "pad": "x" * pad})
    rec.close()


def _lines(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def _note(path: Path, first: int, last: int) -> None:
    """The lock file's note, as a recorder killed while records ``first``..``last`` waited (on
    a full disk, or being written back) leaves it."""
    lost = DroppedRecords(last - first + 1, 100 * (last - first + 1), first, last, (STOPPED,))
    lock_path(path).write_bytes(lock_text(1, lost))


def _one_live_segment(path: Path) -> None:
    _log(path, 30)


def _rotated(path: Path) -> None:
    _log(path, 60, max_bytes=1024)
    assert len(rotated_segments(path)) > 3


def _empty_live_after_rotation(path: Path) -> None:
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("k", {"i": i, "pad": "x" * 60})
    rec._rotate()  # a restart right after a rotation: the live segment is empty
    rec.close()
    assert path.stat().st_size == 0


def _damaged_lines(path: Path) -> None:
    _log(path, 10)
    lines = _lines(path)
    damage = [b"garbage\n", b"[1,2]\n", b'{"seq":"7"}\n', b'{"seq":6.5}\n', b'"seq"\n', b"\n"]
    path.write_bytes(b"".join([*lines[:3], *damage, *lines[3:], *damage]))


def _torn_tail(path: Path) -> None:
    _log(path, 5)
    with path.open("ab") as fh:
        fh.write(b'{"seq":6,"kind":"k","payl')


def _records_over_a_block_some_named_lost(path: Path) -> None:
    _log(path, 6, pad=100_000)  # each line longer than the 64 KiB the log is read by
    _note(path, 4, 9)  # killed while writing back 4..9: 4, 5 and 6 reached the log


def _named_lost_across_a_rotation(path: Path) -> None:
    _log(path, 60, max_bytes=1024)
    newest = rotated_segments(path)[-1][1]
    first = json.loads(_lines(newest)[1])["seq"]
    _note(path, first, 63)  # from the newest rotated segment's second record on


def _named_lost_before_an_empty_live_segment(path: Path) -> None:
    _empty_live_after_rotation(path)
    _note(path, 38, 42)


def _named_lost_older_than_the_log(path: Path) -> None:
    _log(path, 30)
    _note(path, 1, 2)  # a note left as it was: both are in the log


def _repeated_seq_at_the_end(path: Path) -> None:
    _log(path, 6)
    with path.open("ab") as fh:
        fh.write(_lines(path)[-1])


def _old_record_copied_at_the_end(path: Path) -> None:
    _log(path, 6)
    with path.open("ab") as fh:
        fh.write(_lines(path)[1])  # seq 2 after 6: the largest is not the last


def _last_seq_garbled(path: Path) -> None:
    _log(path, 6)
    lines = _lines(path)
    path.write_bytes(b"".join([*lines[:5], lines[5].replace(b'"seq":6,', b'"seq":true,', 1)]))


def _object_without_seq_at_the_end(path: Path) -> None:
    _log(path, 6)
    with path.open("ab") as fh:
        fh.write(b'{"kind":"k","payload":{}}\n')


def _live_segment_behind_the_rotated_one(path: Path) -> None:
    _log(path, 60, max_bytes=1024)
    oldest = rotated_segments(path)[0][1]
    path.write_bytes(b"".join(_lines(oldest)[:2]))  # an old copy put back as the live one


READ_FROM_THE_END: dict[str, Callable[[Path], None]] = {
    "one live segment": _one_live_segment,
    "rotated segments": _rotated,
    "a live segment empty just after a rotation": _empty_live_after_rotation,
    "damaged lines": _damaged_lines,
    "a torn tail": _torn_tail,
    "records over 64 KiB, some named lost": _records_over_a_block_some_named_lost,
    "records named lost across a rotation": _named_lost_across_a_rotation,
    "records named lost before an empty live segment": _named_lost_before_an_empty_live_segment,
    "a note older than the log": _named_lost_older_than_the_log,
}
READ_WHOLE: dict[str, Callable[[Path], None]] = {
    "a seq repeated at the end": _repeated_seq_at_the_end,
    "an old record copied at the end": _old_record_copied_at_the_end,
    "the last record's seq garbled": _last_seq_garbled,
    "an object without a seq at the end": _object_without_seq_at_the_end,
    "a live segment behind the rotated one": _live_segment_behind_the_rotated_one,
}


@pytest.mark.parametrize("make", READ_FROM_THE_END.values(), ids=READ_FROM_THE_END.keys())
def test_a_restart_reads_the_end_of_the_log_and_finds_what_a_full_read_finds(
    tmp_path: Path, make: Callable[[Path], None]
) -> None:
    path = tmp_path / "fdr.jsonl"
    make(path)
    _restart_as_a_full_read_would(path, whole=False)
    _restart_as_a_full_read_would(path, whole=False)  # and again, on what the first one left


@pytest.mark.parametrize("make", READ_WHOLE.values(), ids=READ_WHOLE.keys())
def test_a_damaged_end_whose_seq_does_not_rise_is_read_whole(
    tmp_path: Path, make: Callable[[Path], None]
) -> None:
    path = tmp_path / "fdr.jsonl"
    make(path)
    _restart_as_a_full_read_would(path, whole=True)
    _restart_as_a_full_read_would(path, whole=True)


def test_a_restart_on_a_long_live_segment_parses_only_its_end(tmp_path: Path) -> None:
    """Megabytes of records in the live segment: the restart parses its last record (and its
    first line, judged to be a log's), holds about a block in memory, not the segment, and goes
    on at the next seq."""
    path = tmp_path / "fdr.jsonl"
    _log(path, 400, pad=20_000)
    assert path.stat().st_size > 8_000_000
    with pytest.MonkeyPatch.context() as m:
        parsed = _spy_parses(m)
        tracemalloc.start()
        try:
            rec = JsonlFdrRecorder(path, FakeClock())
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    rec.record("k", {"after": "restart"})
    rec.close()
    assert sum(len(text) for text in parsed) < 3 * 65536
    assert peak < 1 << 20, f"{peak} bytes held at the peak"
    assert read_fdr(path)[-1]["seq"] == 401


@pytest.mark.parametrize("block", [1, 2, 7, 100, 4096, 65536])
@pytest.mark.parametrize("make", READ_FROM_THE_END.values(), ids=READ_FROM_THE_END.keys())
def test_the_end_read_a_block_at_a_time_finds_what_a_full_read_finds(
    tmp_path: Path, make: Callable[[Path], None], block: int
) -> None:
    """Whatever the block, however the lines fall across blocks: the largest seq, and the
    seqs from the first the lock file names on, are those of the full read."""
    path = tmp_path / "fdr.jsonl"
    make(path)
    carried = read_lock(lock_path(path))[1]
    back_to = carried.first_seq if carried else None
    found = tail_seqs(_recent(path), back_to, block)
    full = _full_read_seqs(path)
    assert found is not None and max(found) == max(full)
    assert {s for s in found if back_to and s >= back_to} == {
        s for s in full if back_to and s >= back_to
    }
