"""``c3-matcher fdr`` and ``check_fdr``: a flight-data log read back after the flight, every
segment in order; a gap a ``fdr.records_dropped`` note names is a known loss, any other gap, an
unreadable line or ``seq`` going back is damage (exit 1)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.fdr.check import SeqRange
from c3_matcher.testing import FakeClock


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)


def _log(path: Path, n: int, *, max_bytes: int = 1024) -> JsonlFdrRecorder:
    """A recorder at ``path`` holding ``n`` frame records (rotated every ``max_bytes``)."""
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=max_bytes)
    for i in range(n):
        rec.record("matcher.frame_done", {"i": i, "pad": "x" * 100})
    return rec


def _disk_full(fd, data):
    raise OSError(28, "No space left on device")


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = main(argv)
    return status, capsys.readouterr().out


def test_a_rotated_log_is_read_whole_and_said_intact(tmp_path, capsys):
    path = tmp_path / "fdr.jsonl"
    _log(path, 40).close()
    check = check_fdr(path)
    assert len(check.segments) > 2 and check.segments[-1] == path
    assert check.intact and check.records == 40 and check.seqs == SeqRange(1, 40)
    assert check.kinds == {"matcher.frame_done": 40}
    assert [r["payload"]["i"] for r in read_fdr_log(path)] == list(range(40))
    status, out = _run(["fdr", str(path)], capsys)
    assert status == 0
    assert out.splitlines()[0] == f"{path}: intact"
    assert "records: 40, seq 1..40" in out and "matcher.frame_done 40" in out
    status, out = _run(["fdr", str(path), "--json"], capsys)
    report = json.loads(out)
    assert (status, report["intact"], report["records"], report["gaps"]) == (0, True, 40, [])


def test_records_let_go_on_a_full_disk_are_a_known_loss_not_damage(tmp_path, capsys, monkeypatch):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_pending_bytes=1024)
    rec.record("k", {"i": 0})
    real_write = os.write
    monkeypatch.setattr(os, "write", _disk_full)
    for i in range(1, 21):
        with pytest.raises(FdrWriteError):
            rec.record("k", {"i": i, "pad": "x" * 100})
    monkeypatch.setattr(os, "write", real_write)
    rec.close()
    check = check_fdr(path)
    assert check.intact and check.let_go == rec.dropped > 0
    assert check.noted_gaps == (SeqRange(2, rec.dropped + 1),) and check.gaps == ()
    status, out = _run(["fdr", str(path)], capsys)
    assert status == 0
    assert f"let go: {rec.dropped} record(s), seqs 2..{rec.dropped + 1}, each named" in out


def test_a_line_cut_out_a_garbled_line_and_a_repeated_seq_are_damage(tmp_path, capsys):
    path = tmp_path / "fdr.jsonl"
    _log(path, 6, max_bytes=1 << 20).close()
    lines = path.read_bytes().splitlines(keepends=True)
    path.write_bytes(b"".join([*lines[:2], lines[3], b"garbage\n", lines[3], *lines[4:]]))
    check = check_fdr(path)
    assert not check.intact
    assert check.gaps == (SeqRange(3, 3),)
    assert check.went_back == ((4, 4),)
    assert check.unreadable == ("fdr.jsonl:4: not JSON: Expecting value: line 1 column 1 (char 0)",)
    status, out = _run(["fdr", str(path)], capsys)
    assert status == 1
    assert out.splitlines()[0] == f"{path}: damaged"
    assert "gaps no note explains: seqs 3" in out and "seq went back: 4 after 4" in out
    assert "unreadable lines: fdr.jsonl:4: not JSON" in out


def test_records_a_close_could_not_write_are_named_until_the_next_recorder_writes_them(
    tmp_path, capsys, monkeypatch
):
    path = tmp_path / "fdr.jsonl"
    rec = _log(path, 2)
    monkeypatch.setattr(os, "write", _disk_full)
    with pytest.raises(FdrWriteError):
        rec.record("k", {"i": 2})
    with pytest.raises(FdrWriteError):
        rec.close()
    monkeypatch.undo()
    status, out = _run(["fdr", str(path)], capsys)
    assert status == 0  # nothing in the log is damaged: the loss is at its end, and named
    assert "not in the log: 1 record(s), seqs 3, named in fdr.jsonl.lock" in out
    JsonlFdrRecorder(path, FakeClock()).close()
    check = check_fdr(path)
    assert check.not_in_log is None and check.let_go == 1 and check.intact


def test_the_configured_log_is_checked_by_default_and_a_missing_one_is_bad_input(
    tmp_path, capsys, monkeypatch
):
    path = tmp_path / "flights" / "fdr.jsonl"
    _log(path, 3).close()
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(path))
    status, out = _run(["fdr"], capsys)
    assert (status, out.splitlines()[0]) == (0, f"{path}: intact")
    assert main(["fdr", str(tmp_path / "none.jsonl")]) == 2
    assert f"no flight-data log at {tmp_path / 'none.jsonl'}" in capsys.readouterr().err
    assert main(["fdr", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_a_gap_is_explained_only_where_notes_cover_every_seq_of_it():
    notes = (SeqRange(5, 7), SeqRange(8, 9), SeqRange(12, 20))
    assert SeqRange(5, 9).within(notes)
    assert SeqRange(6, 6).within(notes)
    assert not SeqRange(9, 12).within(notes)  # 10 and 11 are named by no note
    assert not SeqRange(4, 5).within(notes)
    assert not SeqRange(1, 1).within(())


@pytest.mark.parametrize(
    ("was", "garbled"),
    [(b'"seq":', b'"sfq":'), (b'"seq":6,', b'"seq":true,'), (b'"seq":6,', b'"seq":6.0,')],
)
def test_a_json_object_without_an_integer_seq_is_damage_not_a_record(
    tmp_path, capsys, was, garbled
):
    """The last line's seq garbled (a bool or a float is no seq): it was counted as a record
    and the log said intact."""
    path = tmp_path / "fdr.jsonl"
    _log(path, 6, max_bytes=1 << 20).close()
    lines = path.read_bytes().splitlines(keepends=True)
    assert lines[5].startswith(b'{"seq":6,')
    path.write_bytes(b"".join([*lines[:5], lines[5].replace(was, garbled, 1)]))
    check = check_fdr(path)
    assert not check.intact and check.records == 5 and check.seqs == SeqRange(1, 5)
    assert check.unreadable == ("fdr.jsonl:6: no seq (a JSON object, not a record)",)
    status, out = _run(["fdr", str(path)], capsys)
    assert status == 1 and out.splitlines()[0] == f"{path}: damaged"
    assert "unreadable lines: fdr.jsonl:6: no seq" in out


@pytest.mark.parametrize(
    "content",
    [
        b'{"frame": 0, "status": "ok"}\n{"frame": 1, "status": "ok"}\n',  # replay's results
        b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\n\x01\x02\n",  # a JPEG
    ],
    ids=["results.jsonl", "jpeg"],
)
def test_a_file_with_no_record_at_all_is_not_called_a_damaged_log(tmp_path, capsys, content):
    """The file beside the FDR in a replay folder, or an image, is the wrong file (exit 2),
    not a flight record to distrust (exit 1); an empty log is still a new, intact one."""
    path = tmp_path / "results.jsonl"
    path.write_bytes(content)
    assert main(["fdr", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: no line is a flight-data record" in err and "not a flight-data log" in err
    path.write_bytes(b"")
    assert main(["fdr", str(path)]) == 0
