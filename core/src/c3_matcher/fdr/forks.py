"""What a process forked from the one that opened a recorder (or composed a matcher) may do with
the copy it inherited: write nothing, and close it without waiting for anything.

A fork copies the whole memory and only the calling thread: a lock another thread of the parent
held at that moment stays held in the child, by a thread that does not exist there, forever. So
closing an inherited recorder takes no lock: it closes this process's own copies of the file
descriptors (no write, no truncation, no unlock: an ``flock`` belongs to the open file, which the
parent still holds, and its log and lock stay the parent's) and returns at once.
"""

from __future__ import annotations

import contextlib
import os

__all__ = ["close_copies", "forked_from"]


def forked_from(pid: int) -> str | None:
    """Why a process forked from process ``pid`` may not use what ``pid`` made; else None."""
    if (here := os.getpid()) == pid:
        return None
    return (
        f"made in process {pid}, and this is process {here}, forked from it (its FDR is that "
        "process's alone); compose the matcher in the process that uses it, after the fork"
    )


def close_copies(*fds: int) -> None:
    """Close this process's copies of the descriptors ``fds`` inherited across a fork (-1:
    none): the files they name, their contents and their locks are left as they are."""
    for fd in fds:
        if fd >= 0:
            with contextlib.suppress(OSError):
                os.close(fd)
