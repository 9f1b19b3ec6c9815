"""Fault injection on the durable FDR: torn tails, ENOSPC and short
writes, rotation with offloaded segments, crashes around rotation, threads, two writers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import FdrOpenError, FdrWriteError, JsonlFdrRecorder, read_fdr
from c3_matcher.fdr.pending import STOPPED, DroppedRecords, lock_text
from c3_matcher.testing import FakeClock

CORE_SRC = Path(__file__).resolve().parents[1] / "src"


def _all_records(rec: JsonlFdrRecorder) -> list[dict]:
    out: list[dict] = []
    for seg in rec.segments():
        if seg.exists():
            result = read_fdr(seg)
            assert result.corrupt == [], seg
            out.extend(result)
    return out


def _one_record_then_a_torn_tail(path: Path) -> None:
    """An FDR at ``path`` with one record, then half a record without its newline (a power
    cut mid-write)."""
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    rec.close()
    with path.open("ab") as fh:
        fh.write(b'{"seq":2,"kind":"k","payl')


def _full_for(prefix: bytes):
    """An ``os.write`` for which the disk is full for data starting with ``prefix`` alone."""
    real_write = os.write

    def write(fd, data):
        if bytes(data[: len(prefix)]) == prefix:
            raise OSError(28, "No space left on device")
        return real_write(fd, data)

    return write


def test_torn_tail_is_cut_on_open_and_kept_aside(tmp_path):
    path = tmp_path / "fdr.jsonl"
    _one_record_then_a_torn_tail(path)
    torn = read_fdr(path)
    assert torn.torn_tail == b'{"seq":2,"kind":"k","payl' and len(torn.corrupt) == 1
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("k", {"i": 1})
    result = read_fdr(path)
    assert result.corrupt == []
    assert [r["kind"] for r in result] == ["k", "fdr.torn_tail_cut", "k"]
    assert [r["seq"] for r in result] == [1, 2, 3]
    assert result[-1]["payload"] == {"i": 1}
    side = again.torn_path.read_text()
    assert '{\\"seq\\":2,\\"kind\\":\\"k\\",\\"payl' in side
    again.close()


def test_read_fdr_reports_corrupt_lines(tmp_path):
    path = tmp_path / "x.jsonl"
    path.write_bytes(b'{"seq":1}\nGARBAGE\n[1,2]\n{"seq":4}\n{"seq":')
    result = read_fdr(path)
    assert [r["seq"] for r in result] == [1, 4]
    assert [n for n, _, _ in result.corrupt] == [2, 3, 5]
    assert result.torn_tail == b'{"seq":'


def test_enospc_after_partial_write_is_rolled_back(tmp_path, monkeypatch):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    rec.record("k", {"i": 0})
    real_write = os.write
    calls = {"n": 0}

    def half_then_enospc(fd, data):
        calls["n"] += 1
        if calls["n"] == 1:
            return real_write(fd, bytes(data[: len(data) // 2]))
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "write", half_then_enospc)
    with pytest.raises(FdrWriteError, match="1 record"):
        rec.record("k", {"i": 1})
    monkeypatch.setattr(os, "write", real_write)
    rec.record("k", {"i": 2})
    result = read_fdr(rec.path)
    assert result.corrupt == []
    assert [r["payload"]["i"] for r in result] == [0, 1, 2]
    assert [r["seq"] for r in result] == [1, 2, 3]


def test_short_writes_are_completed(tmp_path, monkeypatch):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock())
    real_write = os.write
    monkeypatch.setattr(os, "write", lambda fd, data: real_write(fd, bytes(data[:7])))
    for i in range(3):
        rec.record("k", {"i": i})
    monkeypatch.setattr(os, "write", real_write)
    assert [r["payload"]["i"] for r in read_fdr(rec.path)] == [0, 1, 2]


def test_rotation_after_offload_never_overwrites(tmp_path):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock(), max_bytes=1024)
    acknowledged = []
    for i in range(200):
        rec.record("k", {"i": i, "pad": "x" * 60})
        acknowledged.append(i)
        if i % 40 == 39:  # the ground procedure: offload (move away) the oldest segment
            oldest = rec.segments()[0]
            if oldest != rec.path:
                oldest.rename(tmp_path / f"offloaded-{i}-{oldest.name}")
    seen = []
    for p in sorted(tmp_path.glob("offloaded-*")) + rec.segments():
        seen.extend(r["payload"]["i"] for r in read_fdr(p))
    assert sorted(seen) == acknowledged
    numbers = [int(p.name.split(".")[1]) for p in rec.segments()[:-1]]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    rec.close()


def test_seq_and_segment_numbers_survive_restart_after_rotation(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(30):
        rec.record("k", {"i": i, "pad": "x" * 60})
    rec._rotate()  # crash right after a rotation: the live segment is empty
    rec.close()
    assert path.stat().st_size == 0
    for p in rec.segments()[:-1]:  # and every rotated segment was offloaded
        p.rename(tmp_path / ("away-" + p.name))
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    again.record("k", {"i": 30})
    assert read_fdr(path)[0]["seq"] == 31
    for i in range(31, 60):
        again.record("k", {"i": i, "pad": "x" * 60})
    away = {int(p.name.split(".")[1]) for p in tmp_path.glob("away-*")}
    new = {int(p.name.split(".")[1]) for p in again.segments()[:-1]}
    assert new and min(new) > max(away)
    again.close()


def test_crash_between_link_and_unlink_does_not_duplicate(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    for i in range(3):
        rec.record("k", {"i": i})
    rec.close()
    os.link(path, tmp_path / "fdr.000001.jsonl")  # rotation interrupted after the link
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("k", {"i": 3})
    assert [r["seq"] for r in _all_records(again)] == [1, 2, 3, 4]
    again.close()


def test_threads_get_unique_contiguous_seq(tmp_path):
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock(), max_bytes=4096)

    def work(t: int) -> None:
        for i in range(50):
            rec.record("k", {"t": t, "i": i})

    threads = [threading.Thread(target=work, args=(t,)) for t in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    seqs = [r["seq"] for r in _all_records(rec)]
    assert seqs == list(range(1, 401))
    rec.close()


def test_second_writer_is_refused(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.fdr import JsonlFdrRecorder, FdrOpenError
        from c3_matcher.testing import FakeClock
        try:
            JsonlFdrRecorder(__import__("pathlib").Path({str(path)!r}), FakeClock())
        except FdrOpenError as exc:
            print("REFUSED", exc)
            sys.exit(0)
        sys.exit(1)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "another process" in out.stdout and str(os.getpid()) in out.stdout
    rec.close()
    JsonlFdrRecorder(path, FakeClock()).close()  # released on close


def test_path_that_is_a_directory_or_unwritable_is_named(tmp_path):
    with pytest.raises(FdrOpenError, match="is a directory"):
        JsonlFdrRecorder(tmp_path, FakeClock())
    blocker = tmp_path / "not-a-directory"  # unwritable for root too: a file stands in the way
    blocker.write_text("x")
    with pytest.raises(FdrOpenError, match="fdr.path"):
        JsonlFdrRecorder(blocker / "fdr.jsonl", FakeClock())


def test_full_disk_at_rotation_keeps_writing_and_rotates_once_space_returns(tmp_path, monkeypatch):
    """The next segment number cannot be reserved (ENOSPC at the os call): nothing is renamed,
    records go on to the live segment, and the rotation happens once space returns."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    real_replace = os.replace

    def enospc(src, dst):
        raise OSError(28, "No space left on device")

    for i in range(12):
        rec.record("k", {"i": i, "pad": "x" * 60})
    monkeypatch.setattr(os, "replace", enospc)
    for i in range(12, 40):  # past max_bytes: every rotation attempt fails
        rec.record("k", {"i": i, "pad": "x" * 60})
    assert rec.pending == 0
    assert not list(tmp_path.glob("fdr.jsonl.meta.tmp"))  # what the full disk let us take
    monkeypatch.setattr(os, "replace", real_replace)
    for i in range(40, 60):
        rec.record("k", {"i": i, "pad": "x" * 60})
    records = _all_records(rec)
    assert [r["payload"]["i"] for r in records] == list(range(60))
    assert [r["seq"] for r in records] == list(range(1, 61))
    assert len(rec.segments()) >= 3 and rec.path.stat().st_size <= 1024
    rec.close()


def test_failed_rename_at_rotation_leaves_the_live_segment_in_place(tmp_path, monkeypatch):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(12):
        rec.record("k", {"i": i, "pad": "x" * 60})
    real_rename = Path.rename

    def refuse(self, target):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "rename", refuse)
    before = rec.segments()
    for i in range(12, 30):
        rec.record("k", {"i": i, "pad": "x" * 60})
    assert rec.segments() == before and rec.path.stat().st_size > 1024  # kept writing there
    monkeypatch.setattr(Path, "rename", real_rename)
    rec.record("k", {"i": 30})
    numbers = [int(p.name.split(".")[1]) for p in rec.segments()[:-1]]
    assert numbers == list(range(1, len(before) + 1))  # the failed tries reserved one number
    assert [r["payload"]["i"] for r in _all_records(rec)] == list(range(31))
    newest = read_fdr(rec.segments()[-2])
    meta = json.loads(path.with_name(path.name + ".meta").read_text())
    assert meta["last_seq"] >= newest[-1]["seq"]  # so seq never goes back once all is offloaded
    rec.close()


# Each script runs after this, inside a private mount namespace on a 64 KiB tmpfs at ``mnt``: a
# real full filesystem, no root needed where user namespaces are allowed, and nothing mounted
# outside the child process.
_TMPFS_PRELUDE = """
import errno, json, os, sys
from pathlib import Path
sys.path.insert(0, {src!r})
from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder, read_fdr
from c3_matcher.testing import FakeClock
mnt = Path({mnt!r})
os.system(f"mount -t tmpfs -o size=64k tmpfs {{mnt}}")
assert os.statvfs(mnt).f_blocks * os.statvfs(mnt).f_frsize <= 64 * 1024, "tmpfs not mounted"
filler = mnt / "filler"
def fill():  # take every free page (filler.unlink() gives them back)
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
    try:
        while True:
            os.write(fd, b"\\0" * 4096)
    except OSError as exc:
        assert exc.errno == errno.ENOSPC
    os.close(fd)
"""
_FULL_DISK_SCRIPT = """
rec = JsonlFdrRecorder(mnt / "fdr.jsonl", FakeClock(), max_bytes=1024)
rec.record("k", {{"i": 0, "pad": "x" * 60}})
fill()  # take every free page
failed = []
for i in range(1, 60):  # rotations are due from about the 13th record on
    try:
        rec.record("k", {{"i": i, "pad": "x" * 60}})
    except FdrWriteError as exc:
        failed.append(i)
pending_while_full = rec.pending
filler.unlink()  # space returns
rec.flush()
for i in range(60, 80):
    rec.record("k", {{"i": i, "pad": "x" * 60}})
seen = []
for seg in rec.segments():
    result = read_fdr(seg)
    assert result.corrupt == [], seg
    seen.extend(r["payload"]["i"] for r in result)
print(json.dumps({{"failed": failed, "pending_while_full": pending_while_full, "seen": seen,
                  "segments": len(rec.segments()), "pending_after": rec.pending}}))
rec.close()
"""


def test_real_full_filesystem_at_rotation_loses_nothing(tmp_path):
    report = _in_a_full_tmpfs(tmp_path, _FULL_DISK_SCRIPT)
    assert report["failed"], "the filesystem never filled: the test proved nothing"
    assert report["pending_while_full"] > 0
    assert report["pending_after"] == 0
    assert report["seen"] == list(range(80))  # every record, once, in order
    assert report["segments"] >= 3


# The same real full filesystem, closed while records still wait: the lock file takes the note
# of them in bytes it already has, a recorder opened while the disk is still full opens, and once
# space returns the note is the log's next record.
_CLOSED_ON_FULL_DISK_SCRIPT = """
path = mnt / "fdr.jsonl"
rec = JsonlFdrRecorder(path, FakeClock())
rec.record("k", {{"i": 0}})
fill()
refused = 0
for i in range(1, 40):  # the live segment's page fills, then the disk refuses
    try:
        rec.record("k", {{"i": i, "pad": "x" * 200}})
    except FdrWriteError:
        refused += 1
try:
    rec.close()
    closed = "written"
except FdrWriteError as exc:
    closed = str(exc)
reopened = JsonlFdrRecorder(path, FakeClock())  # the disk is still full
pending_on_reopen = reopened.pending
filler.unlink()
reopened.record("k", {{"i": 40}})
reopened.close()
records = read_fdr(path)
print(json.dumps({{"refused": refused, "closed": closed, "pending_on_reopen": pending_on_reopen,
                  "records": [[r["seq"], r["kind"], r["payload"]] for r in records],
                  "corrupt": len(records.corrupt)}}))
"""


def _in_a_full_tmpfs(tmp_path: Path, script: str) -> dict:
    """Run ``script`` after the prelude that mounts the tmpfs (both formatted with ``src`` and
    ``mnt``) in a private mount namespace; the JSON object it prints last."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    out = subprocess.run(
        [
            "unshare",
            "--mount",
            "--map-root-user",
            sys.executable,
            "-c",
            (_TMPFS_PRELUDE + script).format(src=str(CORE_SRC), mnt=str(mnt)),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_records_lost_by_a_close_on_a_real_full_filesystem_are_recorded_once_space_returns(
    tmp_path,
):
    report = _in_a_full_tmpfs(tmp_path, _CLOSED_ON_FULL_DISK_SCRIPT)
    assert report["refused"] > 0, "the filesystem never filled: the test proved nothing"
    assert "lost, the recorder is closed; the next recorder" in report["closed"]
    assert report["pending_on_reopen"] == 0  # the note waits as the note, not as a record
    records, written = report["records"], [r for r in report["records"] if r[1] == "k"]
    note = records[-1]  # written once space returns, after the record that found it
    assert note[1] == "fdr.records_dropped" and records[-2][2] == {"i": 40}
    assert note[2]["count"] == report["refused"]
    seqs = [r[0] for r in records]
    assert seqs == sorted(set(seqs)), "a seq was given twice"
    missing = set(range(1, seqs[-1] + 1)) - set(seqs)
    assert missing == set(range(note[2]["first_seq"], note[2]["last_seq"] + 1))
    assert len(written) + note[2]["count"] == 41 and report["corrupt"] == 0


# A first start on a disk already full: no lock file yet, so no bytes to write the note over.
# The recorder starts, its records wait; once space returns they are written with the lock
# file's bytes, so that a second full disk, a close, is noted for the next recorder as usual.
_FULL_AT_FIRST_START_SCRIPT = """
path, lock = mnt / "fdr.jsonl", mnt / "fdr.jsonl.lock"
def refused(rec, first, pad):
    n = 0
    for i in range(first, first + 3):
        try:
            rec.record("k", {{"i": i, "pad": "x" * pad}})
        except FdrWriteError:
            n += 1
    return n
fill()
rec = JsonlFdrRecorder(path, FakeClock())  # the lock file is new: the disk has no byte for it
lock_at_start = lock.stat().st_size
refused_at_start = refused(rec, 0, 0)
filler.unlink()  # space returns
rec.record("k", {{"i": 3}})
lock_once_written = lock.read_bytes().split(b"\\n")[0].decode()
fill()  # full again: what waits now is named in the lock file's own bytes
refused_later = refused(rec, 4, 5000)
try:
    rec.close()
    closed = "written"
except FdrWriteError as exc:
    closed = str(exc)
filler.unlink()
again = JsonlFdrRecorder(path, FakeClock())
again.record("k", {{"i": 7}})
again.close()
records = read_fdr(path)
print(json.dumps({{"lock_at_start": lock_at_start, "refused_at_start": refused_at_start,
                  "lock_once_written": lock_once_written, "pid": os.getpid(),
                  "refused_later": refused_later, "closed": closed,
                  "records": [[r["seq"], r["kind"], r["payload"]] for r in records],
                  "corrupt": len(records.corrupt)}}))
"""


def test_a_first_start_on_a_real_full_filesystem_starts_and_notes_later_losses(tmp_path):
    """Before, the lock file's first write failed the start: ``compose_root`` raised and the
    matcher did not start."""
    report = _in_a_full_tmpfs(tmp_path, _FULL_AT_FIRST_START_SCRIPT)
    assert report["lock_at_start"] == 0 and report["refused_at_start"] == 3
    assert report["lock_once_written"] == str(report["pid"])
    assert report["refused_later"] == 3, "the filesystem never filled: the test proved nothing"
    assert "lost, the recorder is closed; the next recorder" in report["closed"]
    records = [(seq, kind, payload.get("i")) for seq, kind, payload in report["records"]]
    assert records == [
        (1, "k", 0),
        (2, "k", 1),
        (3, "k", 2),
        (4, "k", 3),
        (8, "fdr.records_dropped", None),
        (9, "k", 7),
    ]
    assert report["records"][4][2]["first_seq"] == 5 and report["records"][4][2]["count"] == 3
    assert report["corrupt"] == 0


def _refuse_lock_writes(monkeypatch: pytest.MonkeyPatch) -> None:
    def full(fd, data, offset):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "pwrite", full)


def test_a_lock_file_that_cannot_be_written_at_start_is_written_with_the_first_record(
    tmp_path, monkeypatch
):
    path = tmp_path / "fdr.jsonl"
    lock = path.with_name("fdr.jsonl.lock")
    _refuse_lock_writes(monkeypatch)
    rec = JsonlFdrRecorder(path, FakeClock())  # raised FdrOpenError: the matcher never started
    assert rec.pending == 0 and lock.read_bytes() == b""
    rec.record("k", {"i": 0})  # the log has room, the lock file not yet: tried again later
    assert lock.read_bytes() == b""
    monkeypatch.undo()
    rec.record("k", {"i": 1})
    assert lock.read_bytes() == lock_text(os.getpid(), None)
    rec.close()
    assert [r["seq"] for r in read_fdr(path)] == [1, 2]


def test_a_second_recorder_beside_one_started_on_a_full_disk_is_told_what_holds_the_path(
    tmp_path, monkeypatch
):
    """Its lock file names no pid yet: the refusal said "another process (pid ?)", also to the
    process that holds it."""
    path = tmp_path / "fdr.jsonl"
    _refuse_lock_writes(monkeypatch)
    first = JsonlFdrRecorder(path, FakeClock())
    with pytest.raises(FdrOpenError) as refused:
        JsonlFdrRecorder(path, FakeClock())
    said = str(refused.value)
    assert "names no pid yet" in said and "close it first" in said and "pid ?" not in said
    first.close()


def test_a_note_the_lock_file_holds_stays_until_the_log_says_it_when_it_cannot_be_rewritten(
    tmp_path, monkeypatch
):
    """The note of records a killed recorder lost is kept as it was while the lock file cannot
    be written (a copy-on-write filesystem), so a second kill still leaves it for the next."""
    path = tmp_path / "fdr.jsonl"
    JsonlFdrRecorder(path, FakeClock()).close()
    lock = path.with_name("fdr.jsonl.lock")
    noted = lock_text(1, DroppedRecords(2, 200, 1, 2, (STOPPED,)))
    lock.write_bytes(noted)
    _refuse_lock_writes(monkeypatch)
    monkeypatch.setattr(os, "write", _disk_full)
    rec = JsonlFdrRecorder(path, FakeClock())
    assert lock.read_bytes() == noted
    monkeypatch.undo()
    rec.record("k", {"i": 0})
    rec.close()
    assert lock.read_bytes() == lock_text(os.getpid(), None)
    records = read_fdr(path)
    assert [r["kind"] for r in records] == ["k", "fdr.records_dropped"]
    assert [r["seq"] for r in records] == [3, 4] and _counts(records[1]) == (2, 1, 2)


def test_a_torn_tail_note_that_cannot_be_written_yet_is_kept_pending(tmp_path, monkeypatch):
    """A full disk just as the recorder opens over a torn tail: it opens, the
    ``fdr.torn_tail_cut`` record waits, and the next record writes it first."""
    path = tmp_path / "fdr.jsonl"
    _one_record_then_a_torn_tail(path)
    real_write = os.write
    monkeypatch.setattr(os, "write", _full_for(b'{"seq":'))  # the side file still has room
    again = JsonlFdrRecorder(path, FakeClock())
    assert again.pending == 1
    monkeypatch.setattr(os, "write", real_write)
    again.record("k", {"i": 1})
    again.close()
    assert [(r["seq"], r["kind"]) for r in read_fdr(path)] == [
        (1, "k"),
        (2, "fdr.torn_tail_cut"),
        (3, "k"),
    ]


def test_a_new_segment_and_the_directories_made_for_it_are_fsynced(tmp_path, monkeypatch):
    """A power cut after the first acknowledged record must not take the file's (or its new
    directories') entries away: each directory that gained an entry is fsynced."""
    synced: list[str] = []
    real_fsync = os.fsync

    def spy(fd):
        synced.append(str(Path(f"/proc/self/fd/{fd}").readlink()))
        return real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    path = tmp_path / "a" / "b" / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    rec.close()
    assert {str(tmp_path), str(tmp_path / "a"), str(tmp_path / "a" / "b")} <= set(synced)
    assert synced.index(str(tmp_path / "a" / "b")) < synced.index(str(path))


def test_a_file_name_with_glob_characters_keeps_its_rotated_segments(tmp_path):
    path = tmp_path / "fdr[1]*.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("k", {"i": i, "pad": "x" * 60})
    assert len(rec.segments()) >= 3
    rec.close()
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    again.record("k", {"i": 40})
    assert [r["payload"]["i"] for r in _all_records(again)] == list(range(41))
    assert [r["seq"] for r in _all_records(again)] == list(range(1, 42))
    again.close()


def test_closing_with_records_the_disk_still_refuses_says_they_are_lost(tmp_path, monkeypatch):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    monkeypatch.setattr(os, "write", lambda fd, data: (_ for _ in ()).throw(OSError(28, "full")))
    with pytest.raises(FdrWriteError):
        rec.record("k", {"i": 1})
    with pytest.raises(FdrWriteError, match="1 record.* lost.*records them as fdr.records_dropped"):
        rec.close()
    monkeypatch.undo()
    again = JsonlFdrRecorder(path, FakeClock())  # the lock was given back all the same
    again.record("k", {"i": 2})
    again.close()
    records = read_fdr(path)
    assert [(r["seq"], r["kind"]) for r in records] == [
        (1, "k"),
        (3, "fdr.records_dropped"),  # seq 2 is never given again: the note names it
        (4, "k"),
    ]
    assert _counts(records[1]) == (1, 2, 2)
    assert records[1]["payload"]["reasons"] == [
        "the recorder stopped (closed, killed or out of power) while the disk refused them"
    ]
    JsonlFdrRecorder(path, FakeClock()).close()  # the lock no longer names them: said once
    assert len(read_fdr(path)) == 3


def _counts(note: dict) -> tuple[int, int, int]:
    """A ``fdr.records_dropped`` record's count, first seq and last seq."""
    assert note["kind"] == "fdr.records_dropped"
    return note["payload"]["count"], note["payload"]["first_seq"], note["payload"]["last_seq"]


def test_records_waiting_when_the_recorder_is_killed_are_noted_by_the_next_one(tmp_path):
    """``kill -9`` (or a power cut) while the disk refuses records: the lock file already names
    them, so the next recorder gives none of their seqs again and records the loss."""
    path = tmp_path / "fdr.jsonl"
    script = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder
        from c3_matcher.testing import FakeClock
        rec = JsonlFdrRecorder(__import__("pathlib").Path({str(path)!r}), FakeClock())
        rec.record("k", {{"i": 0}})
        def full(fd, data):
            raise OSError(28, "No space left on device")
        os.write = full
        for i in range(1, 4):
            try:
                rec.record("k", {{"i": i}})
            except FdrWriteError:
                pass
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == -9, out.stderr
    JsonlFdrRecorder(path, FakeClock()).close()
    records = read_fdr(path)
    assert [r["seq"] for r in records] == [1, 5]
    assert _counts(records[1]) == (3, 2, 4)


def test_a_note_of_waiting_records_counts_only_those_the_log_lacks(tmp_path):
    """What a kill leaves while waiting records were being written back: the lock file names
    seqs 3-6, the log holds 1-4. The next recorder says 2 were lost (5 and 6) and goes on at 7;
    a note all of whose records reached the log is not written at all."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    for i in range(4):
        rec.record("k", {"i": i})
    rec.close()
    lock = path.with_name("fdr.jsonl.lock")
    lock.write_bytes(lock_text(1, DroppedRecords(4, 400, 3, 6, (STOPPED,))))
    JsonlFdrRecorder(path, FakeClock()).close()
    note = read_fdr(path)[-1]
    assert (note["seq"], *_counts(note)) == (7, 2, 3, 6)
    lock.write_bytes(lock_text(1, DroppedRecords(2, 200, 3, 4, (STOPPED,))))
    JsonlFdrRecorder(path, FakeClock()).close()
    assert len(read_fdr(path)) == 5  # 3 and 4 are both in the log: nothing was lost


def test_records_lost_at_close_are_noted_across_reopens_on_a_disk_still_full(tmp_path, monkeypatch):
    """Reopened while the disk is still full, the recorder opens, keeps the note waiting and,
    closed again, carries it on with the records it lost itself: one note, once space returns."""
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    monkeypatch.setattr(os, "write", _disk_full)
    with pytest.raises(FdrWriteError):
        rec.record("k", {"i": 1})
    with pytest.raises(FdrWriteError, match="lost"):
        rec.close()
    again = JsonlFdrRecorder(path, FakeClock())
    with pytest.raises(FdrWriteError):
        again.record("k", {"i": 2})
    with pytest.raises(FdrWriteError, match="1 record\\(s\\) pending.*lost"):
        again.close()
    monkeypatch.undo()
    JsonlFdrRecorder(path, FakeClock()).close()
    records = read_fdr(path)
    assert [r["seq"] for r in records] == [1, 4]
    assert _counts(records[1]) == (2, 2, 3)


def test_a_lock_file_that_holds_no_note_of_ours_is_not_read_as_one(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0})
    rec.close()
    lock = path.with_name("fdr.jsonl.lock")
    for text in (
        '99\n{"count": 3}\n',
        '99\n{"count":1,"size_bytes":1,"first_seq":"2","last_seq":9,"reasons":[]}\n',
        "99\nnot json\n",
        "",
    ):
        lock.write_text(text)
        JsonlFdrRecorder(path, FakeClock()).close()
    assert [r["seq"] for r in read_fdr(path)] == [1]


def test_a_torn_tail_is_cut_even_when_the_disk_has_no_room_to_keep_it(tmp_path, monkeypatch):
    """The recorder must still open (the vehicle's matcher starts): the cut bytes belong to no
    acknowledged record, and the note says they could not be kept."""
    path = tmp_path / "fdr.jsonl"
    _one_record_then_a_torn_tail(path)
    monkeypatch.setattr(os, "write", _full_for(b'{"segment":'))  # the records still have room
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("k", {"i": 1})
    again.close()
    result = read_fdr(path)
    assert result.corrupt == []
    note = result[1]
    assert note["kind"] == "fdr.torn_tail_cut" and note["payload"]["kept_in"] is None
    assert "No space left" in note["payload"]["not_kept"]
    assert [r["seq"] for r in result] == [1, 2, 3]


def _disk_full(fd, data):
    raise OSError(28, "No space left on device")


def test_a_disk_full_for_long_holds_at_most_max_pending_bytes_and_says_what_it_let_go(
    tmp_path, monkeypatch
):
    """Memory stays bounded while the disk refuses every record: the oldest waiting ones are let
    go, the newest kept; once space returns, the kept ones are written in order and one
    ``fdr.records_dropped`` record names the seqs that are missing, so ``seq`` only gaps there."""
    rec = JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock(), max_pending_bytes=4096)
    rec.record("k", {"i": 0})
    real_write = os.write
    monkeypatch.setattr(os, "write", _disk_full)
    for i in range(1, 101):
        with pytest.raises(FdrWriteError, match="record\\(s\\) pending"):
            rec.record("k", {"i": i, "pad": "x" * 100})
    held, let_go = rec.pending, rec.dropped
    assert 0 < held < 100 and held + let_go == 100
    with pytest.raises(FdrWriteError, match=f"{let_go} let go"):
        rec.flush()
    monkeypatch.setattr(os, "write", real_write)
    rec.flush()
    assert (rec.pending, rec.dropped) == (0, let_go)
    records = read_fdr(rec.path)
    assert records.corrupt == []
    kept = list(range(101 - held, 101))
    assert [r["payload"]["i"] for r in records[:-1]] == [0, *kept]
    assert [r["seq"] for r in records] == [1, *(i + 1 for i in kept), 102]
    note = records[-1]
    assert note["kind"] == "fdr.records_dropped"
    assert {k: note["payload"][k] for k in ("count", "first_seq", "last_seq")} == {
        "count": let_go,
        "first_seq": 2,
        "last_seq": let_go + 1,
    }
    assert sum(len(json.dumps(r, separators=(",", ":"))) + 1 for r in records[1:-1]) <= 4096
    rec.record("k", {"i": 101})
    assert read_fdr(rec.path)[-1]["seq"] == 103
    rec.close()


def _let_go_then_room_but_for(path: Path, blocked: bytes, monkeypatch) -> JsonlFdrRecorder:
    """A recorder at ``path`` whose disk refused 20 records (16 let go, seqs 17-20 kept), then
    has room again for every write but those starting with ``blocked``."""
    rec = JsonlFdrRecorder(path, FakeClock(), max_pending_bytes=1024)
    room_for = _full_for(blocked)
    monkeypatch.setattr(os, "write", _disk_full)
    for i in range(20):
        with pytest.raises(FdrWriteError):
            rec.record("k", {"i": i, "pad": "x" * 100})
    assert (rec.pending, rec.dropped) == (4, 16)
    monkeypatch.setattr(os, "write", room_for)
    return rec


def test_the_note_of_records_let_go_waits_like_any_record(tmp_path, monkeypatch):
    """Room for the kept records but not yet for the note: the next record is written first
    and the note after it (``seq`` never goes back in the file)."""
    rec = _let_go_then_room_but_for(tmp_path / "fdr.jsonl", b'{"seq":21,', monkeypatch)
    with pytest.raises(FdrWriteError, match="0 record\\(s\\) pending, 16 let go"):
        rec.flush()
    monkeypatch.undo()
    rec.record("k", {"i": 20})
    rec.close()
    tail = [(r["seq"], r["kind"]) for r in read_fdr(rec.path)][-6:]
    assert tail == [(s, "k") for s in range(17, 22)] + [(22, "fdr.records_dropped")]


def test_closing_before_the_note_of_records_let_go_is_written_says_so(tmp_path, monkeypatch):
    rec = _let_go_then_room_but_for(tmp_path / "fdr.jsonl", b'{"seq":21,', monkeypatch)
    with pytest.raises(FdrWriteError, match="0 record\\(s\\) pending, 16 let go: lost"):
        rec.close()
    assert [r["seq"] for r in read_fdr(rec.path)] == [17, 18, 19, 20]
    monkeypatch.undo()
    JsonlFdrRecorder(rec.path, FakeClock()).close()  # the next recorder says it
    note = read_fdr(rec.path)[-1]
    assert (note["seq"], *_counts(note)) == (21, 16, 1, 16)


def test_max_pending_bytes_below_a_kilobyte_is_refused(tmp_path):
    with pytest.raises(InvalidInputError, match="fdr.max_pending_bytes.*>= 1024, got 10"):
        JsonlFdrRecorder(tmp_path / "fdr.jsonl", FakeClock(), max_pending_bytes=10)
