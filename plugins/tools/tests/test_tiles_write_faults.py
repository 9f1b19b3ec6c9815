"""``tiles build``'s OUT as a fault of where it is written: a store that cannot be written (a
file-size limit, as a full disk) is said of OUT (exit 2, nothing left), and an OUT that is not a
regular file (a device node, a FIFO, a socket) is refused, ``--force`` or not, and left as it
was."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"

C3 = Callable[..., subprocess.CompletedProcess[str]]  # conftest.py's fixture


@pytest.mark.parametrize(
    "limit",
    [4 << 10, 50 << 10, 1000 << 10],
    ids=["creating the schema", "writing tiles", "committing"],
)
def test_a_store_past_the_file_size_limit_is_said_of_out(
    tmp_path: Path, c3: C3, limit: int
) -> None:
    r = c3("tiles", "build", NAIP_2020, "out.mbtiles", limit_file_bytes=limit)
    assert r.returncode == 2, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last == "c3-matcher: mbtiles: out.mbtiles: cannot be written: disk I/O error", last
    assert list(tmp_path.iterdir()) == []  # no store, no temporary file, no journal


def _fifo(path: Path) -> None:
    os.mkfifo(path)


def _socket(path: Path) -> None:
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(path.name)  # relative: a socket's path is at most 107 bytes


def _device(path: Path) -> None:
    """A character device made here with /dev/null's numbers where this process may make one;
    else a link here to the system's (a build that replaced it would replace the link)."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:
        path.symlink_to("/dev/null")


@pytest.mark.parametrize(
    ("make", "kind"),
    [(_fifo, "a FIFO"), (_socket, "a socket"), (_device, "a character device")],
    ids=["fifo", "socket", "device"],
)
@pytest.mark.parametrize("force", [True, False], ids=["force", "no-force"])
def test_an_out_that_is_not_a_regular_file_is_refused_and_left_as_it_was(
    tmp_path: Path,
    c3: C3,
    monkeypatch: pytest.MonkeyPatch,
    make: Callable[[Path], None],
    kind: str,
    force: bool,
) -> None:
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out.mbtiles"
    make(out)
    before = out.lstat()
    r = c3("tiles", "build", NAIP_2020, "out.mbtiles", *(["--force"] if force else []))
    assert r.returncode == 2, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last == f"c3-matcher: mbtiles: out.mbtiles is {kind}, not a file: it is never replaced"
    after = out.lstat()
    assert (after.st_mode, after.st_ino, after.st_rdev) == (
        before.st_mode,
        before.st_ino,
        before.st_rdev,
    )
    assert [p.name for p in tmp_path.iterdir()] == ["out.mbtiles"]


def test_a_directory_at_out_is_refused_without_force_too(tmp_path: Path, c3: C3) -> None:
    """Not "exists (use --force)": --force would not replace it either."""
    (tmp_path / "out.mbtiles").mkdir()
    r = c3("tiles", "build", NAIP_2020, "out.mbtiles")
    assert r.returncode == 2, r.stderr
    assert "out.mbtiles is a directory, not a file" in r.stderr, r.stderr
