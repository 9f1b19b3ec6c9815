"""A path holding a JSON document (a settings file, a report, a GeoJSON) is not a flight-data
log: the recorder refuses it and never cuts or appends to it. It used to take any file whose
first byte is ``{`` for its own log: a last line without a newline was cut into ``.torn`` and
records were appended. A log is judged by its first line as the recorder writes it: a JSON
object with every key of a record, or, in a file with no newline yet, the start of one cut by a
power cut. The recorder's own logs, rotated or not, are reopened and appended to as before."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, read_fdr, read_fdr_log
from c3_matcher.fdr.files import is_foreign
from c3_matcher.testing import FakeClock

from .demo_match import run_match

REFUSED = "holds something other than flight-data records: give another path"
SETTINGS = {"frames": [1, 2, 3], "note": "my settings"}
RECORD = b'{"seq":1,"kind":"k","recorded_at_ns":5,"wall_time":"2024-01-05T00:00:00Z","payload":{}}'
FOREIGN = {
    "pretty JSON, a final newline": (json.dumps(SETTINGS, indent=2) + "\n").encode(),
    "pretty JSON, no final newline": json.dumps(SETTINGS, indent=2).encode(),
    "one-line JSON, a final newline": (json.dumps(SETTINGS) + "\n").encode(),
    "one-line JSON, no final newline": json.dumps(SETTINGS).encode(),
    "an object with some of a record's keys": b'{"seq":1,"kind":"k"}\n',
    "an empty object, no newline": b"{}",
    "a JSON list of records": b"[" + RECORD + b"]\n",
    "a first line that is not a record": b'{"type":"FeatureCollection"}\n' + RECORD + b"\n",
    "a first line over 64 KiB, not a record": b'{"note":"' + b"x" * 70_000 + b'"}\n',
}


def _files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())}


@pytest.mark.parametrize("fresh", [False, True])
@pytest.mark.parametrize("content", FOREIGN.values(), ids=FOREIGN.keys())
def test_a_json_document_is_refused_and_left_as_it_was(
    tmp_path: Path, content: bytes, fresh: bool
) -> None:
    path = tmp_path / "settings.json"
    path.write_bytes(content)
    with pytest.raises(FdrOpenError) as refused:
        JsonlFdrRecorder(path, FakeClock(), fresh=fresh)
    assert str(refused.value) == f"fdr.path {path}: {REFUSED}"
    assert _files(tmp_path) == {"settings.json": content}  # no .torn, no .lock


def test_match_with_an_fdr_that_is_a_json_document_prints_the_result_and_exits_2(
    tmp_path: Path,
) -> None:
    settings = tmp_path / "settings.json"
    content = json.dumps(SETTINGS, indent=2).encode()
    settings.write_bytes(content)
    out = run_match("--fdr", str(settings))
    assert out.returncode == 2, out.stderr
    assert json.loads(out.stdout)["per_candidate"]  # the result was printed
    naming = [line for line in out.stderr.splitlines() if str(settings) in line]
    assert naming == [
        f"c3-matcher: fdr.path {settings}: {REFUSED}; the result was printed but "
        "NOT recorded in the FDR"
    ]
    assert _files(tmp_path) == {"settings.json": content}


def test_a_log_of_the_recorder_is_reopened_and_appended_to(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 0, "big": "x" * 70_000})  # a first line longer than is read to judge
    rec.record("k", {"i": 1})
    rec.close()
    assert not is_foreign(path)
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("k", {"i": 2})
    again.close()
    result = read_fdr(path)
    assert result.ok and [r["payload"]["i"] for r in result] == [0, 1, 2]
    assert [r["seq"] for r in result] == [1, 2, 3]
    assert not again.torn_path.exists()


def test_a_rotated_log_is_reopened_and_each_segment_is_a_log(tmp_path: Path) -> None:
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(30):
        rec.record("k", {"i": i, "pad": "x" * 40})
    rec.close()
    segments = rec.segments()
    assert len(segments) > 2
    assert [is_foreign(p) for p in segments] == [False] * len(segments)
    again = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    again.record("k", {"i": 30, "pad": ""})
    again.close()
    assert [r["payload"]["i"] for r in read_fdr_log(path)] == list(range(31))
    assert not again.torn_path.exists()


TORN_FIRST = {
    "one byte": b"{",
    "a key begun": b'{"se',
    "compact, cut in a value": RECORD[:40],
    "spaced, cut in a value": b'{"seq": 1, "kind": "matcher.fra',
    "whole but for its newline": RECORD,
    "cut, then NUL bytes": RECORD[:30] + b"\0" * 64,
}


@pytest.mark.parametrize("torn", TORN_FIRST.values(), ids=TORN_FIRST.keys())
def test_a_first_record_cut_by_a_power_cut_is_still_cut_as_a_torn_tail(
    tmp_path: Path, torn: bytes
) -> None:
    path = tmp_path / "fdr.jsonl"
    path.write_bytes(torn)
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("k", {"i": 1})
    rec.close()
    assert [r["kind"] for r in read_fdr(path)] == ["fdr.torn_tail_cut", "k"]
    kept = json.loads(rec.torn_path.read_text())
    assert kept["offset"] == 0 and kept["length"] == len(torn)
