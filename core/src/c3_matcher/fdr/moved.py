"""The live segment removed or renamed under a running recorder (an ``rm``, a ``logrotate``-style
``mv``): records written on to the open file would go to a file nobody reads, or to none.

Before each append, and at close, the recorder compares the file it holds open with the one its
path names (:func:`still_there`: an ``fstat`` and an ``lstat``, microseconds beside the
``fsync``); when they differ it reopens the path (:func:`reopen_live`), so that ``seq`` goes on
in a new live segment, keeps its last seq in ``.meta`` (a later start never gives one again,
even should the new segment go too), and says what happened once: a ``SEGMENT_REPLACED`` record
in the new segment (``c3-matcher fdr`` reads it: the seqs that went are no damage, but not in
the log) and a WARNING ``SEGMENT_REPLACED_WARNING`` (:class:`SegmentReplaced`).

A move while the recorder is idle, then a kill (no record, no close), is said by nothing: the
next start cannot know how many records the file that went held, and gives their seqs again.
Knowing it would take a write beside every record (the seq in ``.meta``), which the flight
path does not pay.
"""

from __future__ import annotations

import contextlib
import errno
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from loguru import logger

from c3_matcher.fdr.files import cut_torn_tail, is_foreign, open_for_append, read_meta, write_meta

SEGMENT_REPLACED = "fdr.segment_replaced"
"""The kind of the record a recorder writes in the live segment it had to make anew."""
SEGMENT_REPLACED_WARNING = "c3.fdr.segment_replaced"
"""The kind of the WARNING said when the live segment was removed or renamed under the recorder."""


@dataclass(frozen=True, slots=True)
class SegmentReplaced:
    """The live segment ``segment`` no longer named the file the recorder wrote: that file is
    ``moved_to`` now (None: removed, or moved out of its folder); it holds the records up to
    ``last_seq`` (those let go on a full disk aside, as their note says), the new one the
    records after it."""

    segment: Path
    moved_to: Path | None
    last_seq: int

    def payload(self) -> dict[str, Any]:
        """The ``SEGMENT_REPLACED`` record's payload."""
        return {
            "segment": str(self.segment),
            "moved_to": None if self.moved_to is None else str(self.moved_to),
            "last_seq": self.last_seq,
        }

    def log(self) -> None:
        """The WARNING. Logged by the recorder once its lock is released: the logs' forwarder
        writes the warning to the FDR, maybe this very recorder."""
        went = "was removed" if self.moved_to is None else f"was renamed to {self.moved_to}"
        logger.bind(kind=SEGMENT_REPLACED_WARNING, **self.payload()).warning(
            f"FDR segment {self.segment} {went} while the recorder wrote it (records up to "
            f"seq {self.last_seq} went there): a new segment at {self.segment} takes the "
            f"records from seq {self.last_seq + 1} on"
        )


def still_there(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open at ``fd``: one that has a name (a file
    removed has none) and is the file at ``path`` (a file renamed is not). A path that cannot
    be looked at (a folder made unreadable) is taken to: the open file keeps the records."""
    held = os.fstat(fd)
    if held.st_nlink == 0:
        return False
    try:
        named = os.lstat(path)
    except OSError as exc:
        return exc.errno not in (errno.ENOENT, errno.ENOTDIR)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)


def new_name(fd: int, path: Path) -> Path | None:
    """The name in ``path``'s folder the file open at ``fd`` has now (the first by name when it
    has several); None when it has none there (removed, or moved out of the folder)."""
    held = os.fstat(fd)
    if held.st_nlink == 0:
        return None
    names = []
    with contextlib.suppress(OSError), os.scandir(path.parent) as entries:
        for entry in entries:
            if entry.inode() == held.st_ino and not entry.is_symlink():
                with contextlib.suppress(OSError):
                    if entry.stat(follow_symlinks=False).st_dev == held.st_dev:
                        names.append(entry.name)
    return path.with_name(min(names)) if names else None


def reopen_live(path: Path, torn_path: Path) -> int:
    """The live segment ``path`` opened to append anew (made when absent; never through a link,
    nor a FIFO or a device: ``open_for_append``): refused, as at start-up, when it holds
    something other than records now (the records wait, as on a full disk); a torn last line
    of a file put there is cut first (into ``torn_path``)."""
    fd = open_for_append(path)
    try:
        if is_foreign(path):
            raise OSError(
                errno.EEXIST,
                f"{path} holds something other than flight-data records now: nothing appended",
            )
        cut_torn_tail(path, torn_path)
    except OSError:
        os.close(fd)
        raise
    return fd


def keep_last_seq(meta: Path, last_seq: int) -> None:
    """Keep ``last_seq`` in the ``.meta`` state file ``meta`` (the rest kept as it is) unless it
    holds a later one; a file that cannot be written is let be (the new segment's own records
    carry ``seq`` on)."""
    state = read_meta(meta)
    kept = state.get("last_seq")
    if type(kept) is int and kept >= last_seq:
        return
    with contextlib.suppress(OSError):
        write_meta(meta, {**state, "last_seq": last_seq})
