"""The live segment removed or renamed under a running recorder (an ``rm``, a ``logrotate``-style
``mv``): the records after it go to a new live segment at the path, ``seq`` going on (in this
run and the next), and the log says what happened once: a ``fdr.segment_replaced`` record and a
WARNING ``c3.fdr.segment_replaced``. The recorder's own rotations say nothing of the kind, and a
file put at the path that holds something else is never appended to."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from loguru import logger

from c3_matcher.fdr import FdrWriteError, JsonlFdrRecorder, check_fdr, read_fdr
from c3_matcher.testing import FakeClock

SEGMENT_REPLACED = "fdr.segment_replaced"
SEGMENT_REPLACED_WARNING = "c3.fdr.segment_replaced"


@pytest.fixture
def warnings() -> Iterator[list[dict[str, Any]]]:
    """The WARNING records logged meanwhile, as their ``extra`` fields."""
    said: list[dict[str, Any]] = []
    sink = logger.add(lambda m: said.append(dict(m.record["extra"])), level="WARNING")
    yield said
    logger.remove(sink)


def _seq_kinds(path: Path) -> list[tuple[int, str]]:
    result = read_fdr(path)
    assert result.ok, result.corrupt
    return [(r["seq"], r["kind"]) for r in result]


def test_a_removed_live_segment_is_made_anew_and_seq_goes_on(tmp_path, warnings):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    path.unlink()  # an operator's rm while the recorder writes
    rec.record("b", {})
    rec.record("c", {})
    assert _seq_kinds(path) == [(2, "b"), (3, SEGMENT_REPLACED), (4, "c")]
    note = read_fdr(path)[1]["payload"]
    assert note == {"segment": str(path), "moved_to": None, "last_seq": 1}
    said = [w for w in warnings if w.get("kind") == SEGMENT_REPLACED_WARNING]
    assert said == [{"kind": SEGMENT_REPLACED_WARNING, **note}]
    rec.close()
    again = JsonlFdrRecorder(path, FakeClock())  # a later start gives no seq again
    again.record("d", {})
    again.close()
    assert _seq_kinds(path)[-1] == (5, "d")
    assert check_fdr(path).intact


def test_a_renamed_live_segment_keeps_its_records_and_the_new_one_says_where(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    rec.record("b", {})
    path.rename(tmp_path / "fdr.jsonl.1")  # logrotate's way
    rec.record("c", {})
    rec.close()
    assert _seq_kinds(tmp_path / "fdr.jsonl.1") == [(1, "a"), (2, "b")]
    assert _seq_kinds(path) == [(3, "c"), (4, SEGMENT_REPLACED)]
    assert read_fdr(path)[1]["payload"]["moved_to"] == str(tmp_path / "fdr.jsonl.1")
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("d", {})
    again.close()
    assert _seq_kinds(path)[-1] == (5, "d")


def test_a_segment_removed_before_a_close_gives_no_seq_again(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    rec.record("b", {})
    path.unlink()
    rec.close()  # nothing written since: the close says it, and the next start goes on
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("c", {})
    again.close()
    assert _seq_kinds(path) == [(3, SEGMENT_REPLACED), (4, "c")]


def test_a_segment_moved_before_a_close_that_cannot_say_it_gives_no_seq_again(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    path.unlink()
    path.mkdir()  # the path taken: no segment can be made there at close
    rec.close()
    path.rmdir()
    again = JsonlFdrRecorder(path, FakeClock())
    again.record("b", {})
    again.close()
    assert _seq_kinds(path) == [(2, "b")]


def test_the_recorders_own_rotations_are_no_replacement(tmp_path, warnings):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("k", {"i": i, "pad": "x" * 64})
    segments = rec.segments()
    rec.close()
    assert len(segments) > 2
    kinds = [r["kind"] for s in segments for r in read_fdr(s)]
    assert kinds == ["k"] * 40
    assert not [w for w in warnings if w.get("kind") == SEGMENT_REPLACED_WARNING]


def test_a_file_of_something_else_put_in_its_place_is_never_appended_to(tmp_path):
    path = tmp_path / "fdr.jsonl"
    rec = JsonlFdrRecorder(path, FakeClock())
    rec.record("a", {})
    path.unlink()
    image = b"\x89PNG\r\n\x1a\n" + bytes(range(256))
    path.write_bytes(image)  # someone's file, under the log's name
    with pytest.raises(FdrWriteError, match="something other than flight-data records"):
        rec.record("b", {})
    assert path.read_bytes() == image and rec.pending == 1
    path.unlink()  # moved out of the way: what waits is written, in order
    rec.flush()
    rec.close()
    assert _seq_kinds(path) == [(2, "b"), (3, SEGMENT_REPLACED)]
