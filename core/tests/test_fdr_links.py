"""Two names of one FDR file give one log: a symbolic link to the live segment (or to a folder
above it) shares the real file's lock, rotated segments, ``.meta`` and ``.torn``, so a second
writer is refused whichever name it opens, and the log reads the same by either name."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, check_fdr, read_fdr_log
from c3_matcher.testing import FakeClock

ONE_WRITER = f"this process (pid {os.getpid()}) already writes this FDR"


def _linked(tmp_path: Path) -> tuple[Path, Path]:
    """``link.jsonl -> shared.jsonl`` in ``tmp_path`` (the link relative, as ``ln -s`` makes)."""
    link = tmp_path / "link.jsonl"
    link.symlink_to("shared.jsonl")
    return link, tmp_path / "shared.jsonl"


@pytest.mark.parametrize("first_by_link", [True, False])
def test_a_second_writer_by_another_name_of_the_file_is_refused(
    tmp_path: Path, first_by_link: bool
) -> None:
    link, real = _linked(tmp_path)
    first, second = (link, real) if first_by_link else (real, link)
    rec = JsonlFdrRecorder(first, FakeClock())
    try:
        with pytest.raises(FdrOpenError) as refused:
            JsonlFdrRecorder(second, FakeClock())
        assert str(refused.value).startswith(f"fdr.path {second}: {ONE_WRITER}")  # its name
        rec.record("x.one", {})
    finally:
        rec.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "link.jsonl",
        "shared.jsonl",
        "shared.jsonl.lock",
    ]
    assert link.is_symlink()


def test_a_second_writer_through_a_linked_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "real").mkdir()
    (tmp_path / "logs").symlink_to("real")
    rec = JsonlFdrRecorder(tmp_path / "logs" / "fdr.jsonl", FakeClock())
    try:
        with pytest.raises(FdrOpenError, match="already writes this FDR"):
            JsonlFdrRecorder(tmp_path / "real" / "fdr.jsonl", FakeClock())
    finally:
        rec.close()
    assert rec.path == tmp_path / "real" / "fdr.jsonl"  # the file the name leads to


def test_rotation_through_a_link_keeps_one_log_readable_by_either_name(tmp_path: Path) -> None:
    link, real = _linked(tmp_path)
    rec = JsonlFdrRecorder(link, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("x.tick", {"i": i, "pad": "p" * 40})
    rec.close()
    assert link.is_symlink() and link.readlink() == Path("shared.jsonl")
    rotated = sorted(p.name for p in tmp_path.glob("shared.0*.jsonl"))
    assert len(rotated) > 2 and [p.name for p in tmp_path.glob("link*")] == ["link.jsonl"]
    assert rec.segments() == [tmp_path / name for name in rotated] + [real]
    again = JsonlFdrRecorder(real, FakeClock(), max_bytes=1024)  # by the other name: seq goes on
    again.record("x.tick", {"i": 40})
    again.close()
    for name in (link, real):
        assert [r["seq"] for r in read_fdr_log(name)] == list(range(1, 42))
        check = check_fdr(name)
        assert check.intact and check.records == 41 and check.path == real
        assert check.segments == (*(tmp_path / n for n in rotated), real)


def test_a_fresh_log_through_a_link_removes_the_link_not_the_log_it_leads_to(
    tmp_path: Path,
) -> None:
    link, real = _linked(tmp_path)
    rec = JsonlFdrRecorder(link, FakeClock(), max_bytes=1024)
    for i in range(40):
        rec.record("x.tick", {"i": i, "pad": "p" * 40})
    rec.close()
    JsonlFdrRecorder(link, FakeClock(), fresh=True).close()  # the link goes, never followed
    assert link.is_file() and not link.is_symlink() and list(read_fdr_log(link)) == []
    assert len(list(tmp_path.glob("shared.0*.jsonl"))) > 2
    assert [r["seq"] for r in read_fdr_log(real)] == list(range(1, 41))


def test_a_link_to_a_file_not_made_yet_makes_it_and_its_folders(tmp_path: Path) -> None:
    link = tmp_path / "link.jsonl"
    link.symlink_to(Path("card") / "logs" / "fdr.jsonl")
    rec = JsonlFdrRecorder(link, FakeClock())
    rec.record("x.one", {})
    rec.close()
    real = tmp_path / "card" / "logs" / "fdr.jsonl"
    assert link.is_symlink() and real.is_file() and not link.with_name("link.jsonl.lock").exists()
    assert [r["seq"] for r in read_fdr_log(link)] == [1]
