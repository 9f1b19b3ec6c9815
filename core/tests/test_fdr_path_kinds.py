"""An FDR path that is not a regular file (a character device such as ``/dev/zero``, a FIFO, a
socket) is refused with ``FdrOpenError`` before it is opened: the check that the path holds
records read a device that never ends to its end and waited forever on a FIFO, so ``match
--fdr`` and ``compose_root`` never returned. A path under a file says that file is not a
directory (it said "File exists"). Each start runs in a child process with a time limit, so a
hang fails the test instead of stopping the suite."""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder
from c3_matcher.testing import FakeClock

from .demo_match import run_match

KIND = {"device": "a character device", "fifo": "a FIFO", "socket": "a socket"}


def _not_regular(kind: str) -> str:
    """The refusal of a path of ``kind``, naming what it is."""
    return f"is {KIND[kind]}, not a regular file: give a file path"


def _special(tmp_path: Path, kind: str) -> Path:
    """A ``kind`` of file in ``tmp_path``: ``fifo``, ``socket`` or ``device`` (a character
    device reading NUL bytes without end: one made here as ``/dev/zero`` is, where this process
    may make one; else a link here to the system's, which a recorder that opened it would only
    read and append to, its lock file made here)."""
    path = tmp_path / f"{kind}.jsonl"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        with socket.socket(socket.AF_UNIX) as sock:
            sock.bind(str(path))
    else:
        try:
            os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 5))
        except PermissionError:
            path.symlink_to("/dev/zero")
    return path


def _started(path: Path) -> str:
    """What a recorder started at ``path`` in a child process said (or that it hung)."""
    script = textwrap.dedent(f"""
        from pathlib import Path
        from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder
        from c3_matcher.testing import FakeClock
        try:
            JsonlFdrRecorder(Path({str(path)!r}), FakeClock()).close()
            print("opened")
        except FdrOpenError as exc:
            print(exc)
    """)
    try:
        out = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
        )
    except subprocess.TimeoutExpired:
        return "hung"
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.parametrize("kind", ["device", "fifo", "socket"])
def test_a_path_that_is_not_a_regular_file_is_refused_unread(tmp_path: Path, kind: str) -> None:
    path = _special(tmp_path, kind)
    assert _started(path) == f"fdr.path {path}: {_not_regular(kind)}"
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no lock file beside it


def test_a_link_to_something_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    link = tmp_path / "fdr.jsonl"
    link.symlink_to(_special(tmp_path, "fifo"))
    assert _started(link) == f"fdr.path {link}: {_not_regular('fifo')}"


@pytest.mark.parametrize("under", ["f.jsonl", "deeper/f.jsonl"])
def test_a_path_under_a_file_says_that_file_is_not_a_directory(tmp_path: Path, under: str) -> None:
    afile = tmp_path / "afile"
    afile.write_text("{}\n")
    path = afile / under
    with pytest.raises(FdrOpenError) as refused:
        JsonlFdrRecorder(path, FakeClock())
    assert str(refused.value) == f"fdr.path {path}: {afile} is not a directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_match_with_an_fdr_that_is_a_fifo_prints_the_result_and_exits_2(tmp_path: Path) -> None:
    fifo = _special(tmp_path, "fifo")
    out = run_match("--fdr", str(fifo))
    assert out.returncode == 2, out.stderr
    assert json.loads(out.stdout)["per_candidate"]  # the result was printed
    last = out.stderr.strip().splitlines()[-1]
    assert last == (
        f"c3-matcher: fdr.path {fifo}: {_not_regular('fifo')}; the result was printed but "
        "NOT recorded in the FDR"
    )
