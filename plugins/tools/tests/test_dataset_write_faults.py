"""A dataset that cannot be written (a full disk, a file-size limit) is said of the output: the
copy of the tile store that did not fit, never the tile store it was copied from."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher_tools.dataset.writing import copy_file, write_dataset

C3 = Callable[..., subprocess.CompletedProcess[str]]  # conftest.py's fixture

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"


def test_a_store_copy_over_the_file_size_limit_names_the_copy_not_the_input(
    tmp_path: Path, c3: C3
) -> None:
    # 200 KiB: the rendered frames (about 16 KB each) fit, the store's copy (380 KB) does not
    r = c3("dataset", "render", NAIP_2020, STORE, "ds", "--frames", "4", limit_file_bytes=200 << 10)
    assert r.returncode == 2, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert str(STORE) not in last, last
    assert last == "c3-matcher: ds/tiles.mbtiles: File too large", last  # OUT's, not the tmp's
    assert list(tmp_path.iterdir()) == []  # nothing at OUT or beside it


def test_a_store_that_cannot_be_read_is_named_as_the_input(tmp_path: Path) -> None:
    """The other side of the copy: a failure reading the store names the store."""
    unreadable = tmp_path / "dir.mbtiles"
    unreadable.mkdir()  # opens, but reading it fails (EISDIR)
    root = tmp_path / "ds"
    try:
        write_dataset(root, {"name": "x"}, None, [], store=unreadable)  # type: ignore[arg-type]
    except OSError as exc:
        assert exc.filename == str(unreadable), exc
    else:
        raise AssertionError("a directory was copied as a store")


@pytest.mark.parametrize(
    ("code", "named"), [(errno.ENOSPC, "copy"), (errno.EFBIG, "copy"), (errno.ENOENT, "source")]
)
def test_a_copy_names_the_copy_for_a_fault_only_the_destination_causes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int, named: str
) -> None:
    """A frame image or a store copied into a dataset: shutil names the source for any failure
    (a full disk was said of the user's image)."""
    source, copy = tmp_path / "source.jpg", tmp_path / "copy.jpg"

    def failing(src: Path, dst: Path) -> None:
        raise OSError(code, os.strerror(code), str(src), None, str(dst))

    monkeypatch.setattr(shutil, "copyfile", failing)
    with pytest.raises(OSError) as failed:
        copy_file(source, copy)
    assert failed.value.filename == str({"copy": copy, "source": source}[named])
