"""Output names as long as the file system takes (255 bytes, a multi-byte UTF-8 name's too) are
written: the temporary name beside one keeps its beginning and a tag of the whole name, so it
fits, two long names that begin alike keep apart, and what a killed writer left is still found
and removed by the next. A UTF-8 text file holding a name's byte that is no UTF-8 is written
with Python's escape for it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from c3_matcher.atomic import temporary_sibling, write_text_atomically
from c3_matcher.testing.killed import killed_while_writing

from .demo_match import run_match

_LONG = {"ascii": "d" * 250, "two-byte": "é" * 127, "three-byte": "東" * 85}
"""250, 254 and 255 bytes."""


@pytest.mark.parametrize("kind", sorted(_LONG))
def test_a_name_the_file_system_takes_is_written(tmp_path: Path, kind: str) -> None:
    path = tmp_path / _LONG[kind]
    assert len(os.fsencode(path.name)) <= 255
    assert len(os.fsencode(temporary_sibling(path).name + "-journal")) <= 255
    write_text_atomically(path, "a run\n")
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    assert path.read_text() == "a run\n"


def test_what_a_killed_writer_of_a_long_name_left_is_removed_by_the_next(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / ("r" * 250), "the previous run\n")
    killed_while_writing(
        f"""
        from pathlib import Path
        from c3_matcher.atomic import atomic_writer
        with atomic_writer(Path({str(path)!r})) as fh:
            fh.write("half a run"); fh.flush()
        """
    )
    assert len([p for p in tmp_path.iterdir() if p != path]) == 1
    write_text_atomically(path, "this run\n")
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_two_long_names_that_begin_alike_have_temporary_names_of_their_own(
    tmp_path: Path,
) -> None:
    one, other = tmp_path / ("x" * 240 + "1"), tmp_path / ("x" * 240 + "2")
    assert (
        temporary_sibling(one).name.split(".tmp-")[0]
        != (temporary_sibling(other).name.split(".tmp-")[0])
    )


def test_a_picture_with_a_250_byte_name_is_written_by_match(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    viz = tmp_path / ("v" * 246 + ".png")
    fdr = tmp_path_factory.mktemp("fdr") / "fdr.jsonl"  # its own: tests run side by side
    done = run_match("--viz", str(viz), "--fdr", str(fdr))
    assert done.returncode == 0, done.stderr
    assert viz.is_file() and [p.name for p in tmp_path.iterdir()] == [viz.name]


def test_text_holding_a_byte_that_is_no_utf8_is_written_escaped(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / "report.html", "<td>vol\udce9</td>")
    assert path.read_text(encoding="utf-8") == "<td>vol\\udce9</td>"
