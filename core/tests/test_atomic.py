"""Files replaced whole or not at all: a write that fails part-way (an error, a file size limit)
leaves the previous file whole and no temporary file behind, two writers of one file never share
a temporary file, pictures are written the same way, and what a killed writer left is removed
by the next writer of the file."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.atomic import (
    atomic_writer,
    temporary_sibling,
    write_bytes_atomically,
    write_text_atomically,
)
from c3_matcher.errors import InvalidInputError
from c3_matcher.testing.killed import killed_while_writing
from c3_matcher.viz import write_png


def test_a_write_that_fails_part_way_leaves_the_previous_file_whole(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / "results.jsonl", "the previous run\n")
    with pytest.raises(RuntimeError), atomic_writer(path) as fh:
        fh.write("half of this run")
        raise RuntimeError("interrupted")
    assert path.read_text() == "the previous run\n"
    assert [p.name for p in tmp_path.iterdir()] == ["results.jsonl"]


_WRITES = {
    "text": "write_text_atomically(path, 'x' * 100_000)",
    "picture": "write_png(np.random.default_rng(0).integers(0, 256, (200, 200, 3), 'u1'), path)",
}


@pytest.mark.parametrize("kind", sorted(_WRITES))
def test_a_write_past_the_file_size_limit_leaves_the_previous_file_whole(
    tmp_path: Path, kind: str
) -> None:
    path = write_bytes_atomically(tmp_path / "previous.png", b"the previous run")
    script = textwrap.dedent(f"""
        import resource
        from pathlib import Path
        import numpy as np
        from c3_matcher.atomic import write_text_atomically
        from c3_matcher.viz import write_png
        path = Path({str(path)!r})
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        try:
            {_WRITES[kind]}
        except OSError as exc:
            print("REFUSED", exc)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert "REFUSED" in proc.stdout, proc.stderr
    assert path.read_bytes() == b"the previous run"
    assert [p.name for p in tmp_path.iterdir()] == ["previous.png"]


def test_nested_writers_of_one_file_each_have_their_own_temporary_file(tmp_path: Path) -> None:
    path = tmp_path / "report.json"
    with atomic_writer(path) as outer:
        outer.write("outer")
        with atomic_writer(path) as inner:
            inner.write("inner")
        assert path.read_text() == "inner"
    assert path.read_text() == "outer"


def test_a_picture_replaces_the_previous_one_whole(tmp_path: Path) -> None:
    import cv2

    path = write_png(np.zeros((8, 8, 3), np.uint8), tmp_path / "inliers.png")
    red = np.zeros((8, 8, 3), np.uint8)
    red[..., 0] = 255
    write_png(red, path)
    read = cv2.imread(str(path))
    assert read is not None and read.shape == (8, 8, 3)
    assert (read[..., 2] == 255).all() and (read[..., :2] == 0).all()  # BGR on disk
    assert [p.name for p in tmp_path.iterdir()] == ["inliers.png"]


def test_an_output_that_cannot_be_written_is_refused_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c3_matcher import atomic
    from c3_matcher.atomic import refuse_unwritable

    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder\n")
    with pytest.raises(InvalidInputError, match="a_file is not a directory") as info:
        refuse_unwritable(a_file, field="--out", directory=True)
    assert info.value.field == "--out"
    with pytest.raises(InvalidInputError, match="a_file is not a directory"):
        refuse_unwritable(a_file / "deeper" / "x.mbtiles")
    refuse_unwritable(a_file)  # a file to replace, in a writable folder
    refuse_unwritable(tmp_path / "new" / "deeper", directory=True)  # made on writing
    assert not (tmp_path / "new").exists()
    monkeypatch.setattr(atomic.os, "access", lambda path, mode: False)  # a read-only mount
    with pytest.raises(InvalidInputError, match=f"{tmp_path} is not writable"):
        refuse_unwritable(tmp_path / "new" / "deeper", directory=True)


def test_a_write_that_fails_names_the_file_asked_for_not_its_temporary_file(
    tmp_path: Path,
) -> None:
    """``--viz`` naming a folder said ``Is a directory: '.viz.png.123-ab.tmp' -> ...``."""
    folder = tmp_path / "pictures"
    folder.mkdir()
    with pytest.raises(IsADirectoryError) as info:
        write_png(np.zeros((8, 8, 3), np.uint8), folder)
    assert info.value.filename == str(folder) and ".tmp" not in str(info.value)
    with pytest.raises(FileNotFoundError) as missing:
        write_text_atomically(tmp_path / "gone" / "results.jsonl", "x")
    assert missing.value.filename == str(tmp_path / "gone" / "results.jsonl")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pictures"]
    assert list(folder.iterdir()) == []


def test_what_a_killed_writer_left_is_removed_by_the_next_writer(tmp_path: Path) -> None:
    path = write_text_atomically(tmp_path / "results.jsonl", "the previous run\n")
    killed_while_writing(
        f"""
        from pathlib import Path
        from c3_matcher.atomic import atomic_writer
        with atomic_writer(Path({str(path)!r})) as fh:
            fh.write("half a run"); fh.flush()
        """
    )
    (left,) = [p for p in tmp_path.iterdir() if p != path]
    assert left.name.startswith(".results.jsonl.tmp-")
    assert path.read_text() == "the previous run\n"  # the kill cost nothing but the leftover
    write_text_atomically(path, "this run\n")
    assert [p.name for p in tmp_path.iterdir()] == ["results.jsonl"]


def test_a_running_writers_and_another_machines_temporary_files_are_left_alone(
    tmp_path: Path,
) -> None:
    path = tmp_path / "report.json"
    running = temporary_sibling(path)  # this process's: it runs
    running.write_text("a writer at work")
    elsewhere = tmp_path / f".report.json.tmp-00000000-{1 << 22}-0123abcd"  # a shared disk
    elsewhere.write_text("another machine's")
    unrelated = tmp_path / ".report.json.swp"
    unrelated.write_text("an editor's")
    write_text_atomically(path, "{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["report.json", running.name, elsewhere.name, unrelated.name]
    )
