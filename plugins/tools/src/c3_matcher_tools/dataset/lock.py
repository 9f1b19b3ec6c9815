"""A dataset directory held while a run reads it (:func:`reading_dataset`, ``replay`` and
``eval``) or while ``dataset import`` or ``render --force`` replaces it
(:func:`replacing_dataset`), so that no run reads frames of two datasets.

The lock is ``flock`` on the dataset directory itself, not on a file inside or beside it: a
run reads images by path frame after frame, and a replacement swaps the directory's name onto
a new one, so what must not change under a run is the directory the name points at. The
replacing writer locks that directory (the one the readers hold) before it swaps; a file
inside would leave with the old directory and one beside would be a stray file among the
user's, where a directory on read-only media takes neither. The kernel lets go when a
process dies, and nothing is written."""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from c3_matcher.errors import InvalidInputError

__all__ = ["reading_dataset", "replacing_dataset"]

_TRIES = 5
"""How often a holder takes the lock again when the name moved to another directory meanwhile."""


def reading_dataset(root: Path) -> contextlib.AbstractContextManager[None]:
    """``root`` held shared while the block runs (several runs read one dataset at once);
    ``InvalidInputError`` naming ``dataset`` and the process replacing it when one is. One
    that is no directory (refused as a dataset later) or cannot be opened is not held."""
    return _holding(
        root,
        fcntl.LOCK_SH,
        "dataset",
        lambda holders: (
            f"another process is replacing this dataset ({holders}): "
            "wait for it to finish, then run again"
        ),
    )


def replacing_dataset(out: Path) -> contextlib.AbstractContextManager[None]:
    """The existing dataset directory ``out`` held alone while the block runs (it builds the
    new one and swaps it in); ``InvalidInputError`` naming ``OUT`` and the process reading
    it when a run (``replay``, ``eval``) does. A missing ``out`` (nothing to read) is not
    held."""
    return _holding(
        out,
        fcntl.LOCK_EX,
        "OUT",
        lambda holders: (
            f"a run is reading this dataset ({holders}); replacing it now "
            "would give that run frames of two datasets: wait for it to finish, or "
            "choose another OUT"
        ),
    )


@contextlib.contextmanager
def _holding(root: Path, how: int, field: str, refusal: Callable[[str], str]) -> Iterator[None]:
    """The directory ``root`` names held ``how`` while the block runs; ``InvalidInputError``
    naming ``field`` and saying ``refusal`` of the holders when another process holds it the
    other way. Taken again when the name moved to another directory between the open and the
    lock, so that what is held is what the name points at (a writer too: it swaps the
    directory it holds)."""
    for _ in range(_TRIES):
        fd = _open_directory(root)
        if fd is None:
            yield
            return
        try:
            if not _locked(fd, how):
                raise InvalidInputError(field, f"{root}: {refusal(_holders(fd))}")
            if _same(root, fd):  # not swapped between the open and the lock
                yield
                return
        finally:
            os.close(fd)
    raise InvalidInputError(field, f"{root}: replaced again and again while being opened")


def _open_directory(path: Path) -> int | None:
    """A descriptor of the directory ``path``; None when it is none or cannot be opened."""
    try:
        return os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return None


def _locked(fd: int, how: int) -> bool:
    """``fd`` locked ``how`` at once; False when another holder prevents it."""
    try:
        fcntl.flock(fd, how | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _same(path: Path, fd: int) -> bool:
    """``path`` still names the directory open as ``fd``."""
    try:
        now, held = path.stat(), os.fstat(fd)
    except OSError:
        return False
    return (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino)


def _holders(fd: int) -> str:
    """The processes that hold a lock on the directory open as ``fd``, as ``/proc/locks``
    names them (process id and command line); "another process" where they cannot be told."""
    st = os.fstat(fd)
    where = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return "another process"
    pids = {
        int(f[4])
        for f in (line.split() for line in lines)
        if len(f) > 5 and f[1] == "FLOCK" and f[5] == where and f[4].isdigit()
    }
    said = [_process(pid) for pid in sorted(pids)]
    return "; ".join(said) or "another process"


def _process(pid: int) -> str:
    """``pid`` and its command line, shortened."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return f"process {pid}"
    words = " ".join(os.fsdecode(a) for a in argv if a)
    return f"process {pid}: {words[:160]}" if words else f"process {pid}"
