"""A symbolic link left beside a log, where the recorder keeps its lock, ``.meta`` or ``.torn``
(say in an earlier run's output folder), is never written through: the recorder refuses a lock
file that is a link, naming it, and keeps nothing in a ``.torn`` or ``.meta`` link; the file
the link leads to stays as it was. A log started anew (``fresh``, a ground run's) takes a link
at its own name for an old file of the log: the link goes, what it leads to stays."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, read_fdr
from c3_matcher.testing import FakeClock

VICTIM = b"".join(b"%d\n" % i for i in range(1, 2001))  # `seq 1 2000`


def _victim(tmp_path: Path) -> Path:
    """A file elsewhere, that no recorder may change."""
    (tmp_path / "elsewhere").mkdir()
    victim = tmp_path / "elsewhere" / "important.txt"
    victim.write_bytes(VICTIM)
    return victim


@pytest.mark.parametrize("fresh", [False, True])
def test_a_lock_file_that_is_a_link_is_refused_and_its_target_left_as_it_was(
    tmp_path: Path, fresh: bool
) -> None:
    victim = _victim(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    lock = out / "fdr.jsonl.lock"
    lock.symlink_to(victim)
    with pytest.raises(FdrOpenError) as refused:
        JsonlFdrRecorder(out / "fdr.jsonl", FakeClock(), fresh=fresh)
    assert f"{lock} is a symbolic link, not a regular file" in str(refused.value)
    assert victim.read_bytes() == VICTIM
    assert lock.is_symlink() and sorted(p.name for p in out.iterdir()) == ["fdr.jsonl.lock"]


def test_a_lock_file_that_is_a_fifo_is_refused_not_waited_on(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "fdr.jsonl.lock")
    with pytest.raises(FdrOpenError, match=r"fdr\.jsonl\.lock is a FIFO, not a regular file"):
        JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())


def test_a_fresh_log_removes_a_link_at_its_name_never_what_it_leads_to(tmp_path: Path) -> None:
    other = tmp_path / "elsewhere" / "fdr.jsonl"  # another log: its files must all stay
    rec = JsonlFdrRecorder(other, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("x.tick", {"i": i, "pad": "p" * 40})
    rec.close()
    before = {p.name: p.read_bytes() for p in other.parent.iterdir()}
    out = tmp_path / "out"
    out.mkdir()
    (out / "fdr.jsonl").symlink_to(other)
    fresh = JsonlFdrRecorder(out / "fdr.jsonl", FakeClock(), fresh=True)
    fresh.record("x.new", {})
    fresh.close()
    assert {p.name: p.read_bytes() for p in other.parent.iterdir()} == before
    assert not (out / "fdr.jsonl").is_symlink() and fresh.path == out / "fdr.jsonl"
    assert [(r["seq"], r["kind"]) for r in read_fdr(out / "fdr.jsonl")] == [(1, "x.new")]


def test_a_fresh_log_removes_a_link_at_its_name_to_a_folder(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "fdr.jsonl").symlink_to(tmp_path)  # judged by what it is, not where it leads
    JsonlFdrRecorder(out / "fdr.jsonl", FakeClock(), fresh=True).close()
    assert (out / "fdr.jsonl").is_file() and not (out / "fdr.jsonl").is_symlink()


def test_a_torn_tail_is_cut_but_not_kept_in_a_torn_file_that_is_a_link(tmp_path: Path) -> None:
    victim = _victim(tmp_path)
    path = tmp_path / "fdr.jsonl"
    JsonlFdrRecorder(path, FakeClock()).close()
    with path.open("ab") as fh:
        fh.write(b'{"seq":1,"kind":"k","pay')
    (tmp_path / "fdr.jsonl.torn").symlink_to(victim)
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.close()
    assert victim.read_bytes() == VICTIM
    (cut,) = [r["payload"] for r in read_fdr(path) if r["kind"] == "fdr.torn_tail_cut"]
    assert cut["kept_in"] is None and "is a symbolic link" in cut["not_kept"]


def test_a_rotation_writes_no_meta_through_a_link_at_its_temporary_name(tmp_path: Path) -> None:
    victim = _victim(tmp_path)
    path = tmp_path / "fdr.jsonl"
    (tmp_path / "fdr.jsonl.meta.tmp").symlink_to(victim)
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("x.tick", {"i": i, "pad": "p" * 40})
    rec.close()
    assert victim.read_bytes() == VICTIM
    assert len(rec.segments()) > 2 and not (tmp_path / "fdr.jsonl.meta.tmp").exists()


def test_a_rotated_segment_linked_to_the_live_one_is_no_half_rotation(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("x.one", {})
    rec.close()
    (tmp_path / "fdr.000001.jsonl").symlink_to("fdr.jsonl")
    JsonlFdrRecorder(path, FakeClock()).close()
    assert path.is_file() and [r["kind"] for r in read_fdr(path)] == ["x.one"]
