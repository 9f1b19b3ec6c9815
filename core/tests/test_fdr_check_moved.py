"""``c3-matcher fdr`` after another program removed or renamed the live segment under a recorder
(an ``rm``, a ``logrotate`` ``mv``): the gap it leaves is explained by the recorder's own
``fdr.segment_replaced`` note, so the log is no more called damaged, and the report says where
those records went (or that they were removed): not in this log. A move while the recorder is
idle is said at its ``close`` as a write would say it. A gap the note does not explain is still
damage."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.fdr import JsonlFdrRecorder, check_fdr, read_fdr
from c3_matcher.fdr.check import MovedSegment, SeqRange
from c3_matcher.testing import FakeClock

SEGMENT_REPLACED = "fdr.segment_replaced"
CORE_SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)


def _rotated_log(path: Path, n: int = 30) -> tuple[JsonlFdrRecorder, SeqRange]:
    """A recorder at ``path`` holding ``n`` records over several segments, and the seqs its
    live segment holds."""
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=2048)
    for i in range(n):
        rec.record("t", {"i": i, "pad": "x" * 40})
    assert len(rec.segments()) > 2
    return rec, SeqRange(read_fdr(path)[0]["seq"], n)


def _move(path: Path, how: str) -> str | None:
    """The live segment renamed (logrotate's way) or removed: where it is now, if anywhere."""
    if how == "removed":
        path.unlink()
        return None
    moved_to = path.with_name(path.name + "-20261205")
    path.rename(moved_to)
    return str(moved_to)


def _report(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, dict]:
    """``c3-matcher fdr PATH``: its exit status and text, and its ``--json`` report."""
    status = main(["fdr", str(path)])
    text = capsys.readouterr().out
    assert main(["fdr", str(path), "--json"]) == status
    return status, text, json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("how", ["renamed", "removed"])
def test_records_moved_with_the_live_segment_are_named_as_not_in_the_log_not_as_damage(
    tmp_path, capsys, how
):
    path = tmp_path / "c3_fdr.jsonl"
    rec, went = _rotated_log(path)
    moved_to = _move(path, how)
    for i in range(5):
        rec.record("t2", {"i": i})
    rec.close()
    check = check_fdr(path)
    assert check.intact and check.gaps == () and check.noted_gaps == ()
    assert check.moved == (MovedSegment(str(path), moved_to, 30, went),)
    assert check.moved_away == check.moved
    status, text, report = _report(path, capsys)
    assert status == 0 and text.splitlines()[0] == f"{path}: intact"
    assert "gaps no note explains" not in text
    said = (
        f"renamed the live segment {path} to {moved_to}"
        if moved_to
        else f"removed the live segment {path} (or moved it out of its folder)"
    )
    assert f"  moved away: seqs {went}, not in this log: another program {said}" in text
    assert report["intact"] and report["gaps"] == []
    assert report["moved"] == [
        {
            "segment": str(path),
            "moved_to": moved_to,
            "last_seq": 30,
            "missing": {"first": went.first, "last": 30},
        }
    ]


def test_a_gap_past_the_notes_last_seq_is_still_damage(tmp_path, capsys):
    path = tmp_path / "c3_fdr.jsonl"
    rec, went = _rotated_log(path)
    _move(path, "renamed")
    for i in range(5):
        rec.record("t2", {"i": i})
    rec.close()
    lines = path.read_bytes().splitlines(keepends=True)
    assert json.loads(lines[0])["seq"] == 31
    path.write_bytes(b"".join(lines[1:]))  # seq 31, after the note's last seq, cut out
    check = check_fdr(path)
    assert not check.intact and check.gaps == (SeqRange(went.first, 31),)
    status, text, _ = _report(path, capsys)
    assert status == 1 and f"gaps no note explains: seqs {went.first}..31" in text


@pytest.mark.parametrize("how", ["renamed", "removed"])
def test_a_segment_moved_while_the_recorder_is_idle_is_said_at_its_close(tmp_path, capsys, how):
    path = tmp_path / "c3_fdr.jsonl"
    rec, went = _rotated_log(path)
    moved_to = _move(path, how)
    rec.close()  # no record since the move: the close says it
    assert [(r["seq"], r["kind"]) for r in read_fdr(path)] == [(31, SEGMENT_REPLACED)]
    assert read_fdr(path)[0]["payload"] == {
        "segment": str(path),
        "moved_to": moved_to,
        "last_seq": 30,
    }
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=2048)  # the next run
    again.record("next", {})
    again.close()
    assert read_fdr(path)[-1]["seq"] == 32
    check = check_fdr(path)
    assert check.intact and check.moved_away == (MovedSegment(str(path), moved_to, 30, went),)
    status, text, _ = _report(path, capsys)
    assert status == 0 and f"moved away: seqs {went}, not in this log" in text


def test_a_segment_moved_before_the_first_record_of_the_log_is_named_by_its_last_seq(
    tmp_path, capsys
):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    rec.record("b", {})
    path.unlink()
    rec.record("c", {})
    rec.close()
    check = check_fdr(path)
    assert check.intact and check.moved_away == (MovedSegment(str(path), None, 2, None),)
    status, text, _ = _report(path, capsys)
    assert status == 0 and "moved away: records up to seq 2, not in this log" in text


def test_a_move_while_idle_then_a_kill_gives_its_seqs_again_as_the_readme_says(tmp_path):
    """The limit the README states ("if no kill comes first"): nothing wrote or closed after
    the move, so the next start cannot know how many records the file that went held."""
    path = tmp_path / "fdr.jsonl"
    script = textwrap.dedent(f"""
        import os, signal, sys
        from pathlib import Path
        sys.path.insert(0, {str(CORE_SRC)!r})
        from c3_matcher.fdr import JsonlFdrRecorder
        from c3_matcher.testing import FakeClock
        path = Path({str(path)!r})
        rec = JsonlFdrRecorder(path, FakeClock())
        for i in range(3):
            rec.record("k", {{"i": i}})
        path.rename(path.with_name("fdr.jsonl.1"))
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == -signal.SIGKILL, done.stderr
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("next", {})
    again.close()
    assert [r["seq"] for r in read_fdr(path)] == [1]
    assert [r["seq"] for r in read_fdr(tmp_path / "fdr.jsonl.1")] == [1, 2, 3]


def _write_log(path: Path, records: list[tuple[int, str, dict]]) -> None:
    """A log of ``(seq, kind, payload)`` records, written as a recorder writes them."""
    lines = [
        json.dumps({"seq": s, "kind": k, "recorded_at_ns": s, "wall_time": None, "payload": p})
        for s, k, p in records
    ]
    path.write_text("".join(line + "\n" for line in lines))


def test_a_gap_is_held_against_both_notes_records_let_go_first(tmp_path):
    path = tmp_path / "fdr.jsonl"
    moved = {"segment": str(path), "moved_to": None, "last_seq": 5}
    dropped = {"count": 1, "size_bytes": 10, "first_seq": 6, "last_seq": 6, "reasons": []}
    ok = [(1, "a", {}), (2, "a", {}), (7, "b", {}), (8, SEGMENT_REPLACED, moved)]
    _write_log(path, [*ok, (9, "fdr.records_dropped", dropped)])
    check = check_fdr(path)  # 3..5 went with the segment removed, 6 was let go
    assert check.intact and check.let_go == 1 and check.noted_gaps == (SeqRange(6, 6),)
    assert check.moved == (MovedSegment(str(path), None, 5, SeqRange(3, 5)),)
    all_let_go = {**dropped, "count": 4, "first_seq": 3}
    _write_log(path, [*ok, (9, "fdr.records_dropped", all_let_go)])
    check = check_fdr(path)  # all four let go: the note of records let go says so
    assert check.intact and check.noted_gaps == (SeqRange(3, 6),) and check.moved_away == ()
    _write_log(path, ok)  # 6 neither moved nor let go
    assert check_fdr(path).gaps == (SeqRange(3, 6),)
