"""What waits on a full disk: the records accepted but not yet durable (bounded in bytes), the
note of those let go, and the lock file that carries what waits to the next recorder.

The lock file ``<path>.lock`` holds the writer's pid on its first line. While records wait,
the second line names them, as records lost should the recorder stop before writing them
(closed, killed, out of power): a rewrite of bytes the file already has, which needs no new
space on the disk. The next recorder at that path reads it, never gives those seqs again, and
records the loss as ``fdr.records_dropped``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from c3_matcher.fdr.files import NotRegularFileError, make_dirs_durably, open_regular, refusal
from c3_matcher.fdr.records import FdrOpenError
from c3_matcher.json_text import loads_json

LET_GO = "more than [fdr] max_pending_bytes waited while the disk refused them: the oldest went"
STOPPED = "the recorder stopped (closed, killed or out of power) while the disk refused them"
RECORDS_DROPPED = "fdr.records_dropped"  # the kind of the record that names lost records
LOCK_BYTES = 1024  # the lock file's fixed size: room for the pid and a note of lost records
SeqSpan = tuple[int, int]  # the first and last seq of some records


@dataclasses.dataclass(frozen=True, slots=True)
class DroppedRecords:
    """Records accepted but never written: how many, their bytes, the first and last of their
    seqs (every seq between that the file lacks is one of them) and why. Carried to the next
    recorder, the count is of the seqs its log lacks; the bytes stay an upper bound."""

    count: int
    size_bytes: int
    first_seq: int
    last_seq: int
    reasons: tuple[str, ...]

    def without(self, written: Iterable[int]) -> DroppedRecords | None:
        """This note less the records whose seqs are among ``written`` (a recorder killed
        while it wrote waiting records back wrote some of them); ``None`` when none is left.
        ``size_bytes`` stays an upper bound."""
        in_range = {seq for seq in written if self.first_seq <= seq <= self.last_seq}
        count = min(self.count, self.last_seq - self.first_seq + 1 - len(in_range))
        return dataclasses.replace(self, count=count) if count > 0 else None

    def payload(self) -> dict[str, Any]:
        """The ``fdr.records_dropped`` record's payload (and the lock file's note)."""
        return {**dataclasses.asdict(self), "reasons": list(self.reasons)}


def _with(
    note: DroppedRecords | None, count: int, size_bytes: int, seqs: SeqSpan, reason: str
) -> DroppedRecords:
    """``note`` (``None``: nothing dropped yet) and ``count`` more records of ``size_bytes``
    whose seqs lie in ``seqs`` (first, last)."""
    first, last = seqs
    if note is None:
        return DroppedRecords(count, size_bytes, first, last, (reason,))
    return DroppedRecords(
        note.count + count,
        note.size_bytes + size_bytes,
        min(note.first_seq, first),
        max(note.last_seq, last),
        note.reasons if reason in note.reasons else (*note.reasons, reason),
    )


class Pending:
    """Records accepted but not yet durable, oldest first, at most ``max_bytes`` of them (the
    newest is always kept); what is let go to stay within it is counted in ``dropped``."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.records: deque[tuple[int, bytes]] = deque()
        self.size_bytes = 0
        self.dropped: DroppedRecords | None = None  # not yet said by a record
        self.dropped_total = 0

    def hold(self, seq: int, data: bytes) -> None:
        """Keep the record ``seq`` (its line ``data``); let the oldest go past ``max_bytes``."""
        self.records.append((seq, data))
        self.size_bytes += len(data)
        while self.size_bytes > self.max_bytes and len(self.records) > 1:
            old_seq, old = self.records.popleft()
            self.size_bytes -= len(old)
            self.dropped_total += 1
            self.dropped = _with(self.dropped, 1, len(old), (old_seq, old_seq), LET_GO)

    @property
    def waiting(self) -> bool:
        """Records, or the note of those let go, are still to be written."""
        return bool(self.records) or self.dropped is not None

    def written(self) -> None:
        """The oldest record is durable."""
        _, data = self.records.popleft()
        self.size_bytes -= len(data)

    def lost(self) -> DroppedRecords | None:
        """All that waits, as records lost should the recorder stop now (closed, killed or out
        of power) before it could write them."""
        if not self.records:
            return self.dropped
        span = (self.records[0][0], self.records[-1][0])
        return _with(self.dropped, len(self.records), self.size_bytes, span, STOPPED)


def lock_text(pid: int, lost: DroppedRecords | None) -> bytes:
    """The lock file's bytes: ``pid``, then the note of records ``lost`` if any, padded to
    ``LOCK_BYTES`` so that rewriting them never needs new space."""
    text = f"{pid}\n"
    if lost is not None:
        text += json.dumps(lost.payload(), separators=(",", ":")) + "\n"
    data = text.encode()
    return data + b" " * max(0, LOCK_BYTES - len(data))


def lock_path(log: Path) -> Path:
    """The lock file of the log whose live segment is ``log``: ``<log>.lock``."""
    return log.with_name(log.name + ".lock")


def read_lock(path: Path) -> tuple[str, DroppedRecords | None]:
    """The lock file's holder (its pid, "" when unreadable) and its note of lost records."""
    try:
        lines = path.read_bytes()[:LOCK_BYTES].decode("utf-8", errors="replace").splitlines()
    except OSError:
        return "", None
    holder = lines[0].strip()[:32] if lines else ""
    return holder, _note(lines[1]) if len(lines) > 1 else None


def held_by(path: Path) -> str:
    """Why the lock file ``path`` cannot be taken: who holds it (the pid it names)."""
    holder = read_lock(path)[0]
    if not holder:  # its recorder started on a full disk: its pid is written with a record
        return (
            "a recorder is writing this FDR (its lock file names no pid yet: it started on a "
            "full disk), in this process or another: close it first, or give another path; "
            "one writer per path"
        )
    if holder == str(os.getpid()):
        return (
            f"this process (pid {holder}) already writes this FDR (a recorder, or a composed "
            "root, still open): close it first, or give another path; one writer per path, "
            "whether this process or another process"
        )
    return f"another process (pid {holder}) is writing this FDR; one writer per path"


def take_lock(log: Path, what: str, shown: Path, *, fresh: bool = False) -> int:
    """Hold ``lock_path(log)``: its descriptor, locked (``FdrOpenError`` naming ``what`` when
    another recorder holds it, or when the log, by the name ``shown`` it was given, is refused
    by ``refusal``, before anything is made: a directory, not a regular file, under a file
    (named as given), or holding something other than records: never cut, appended to or
    removed; or when the lock file is a symbolic link or no regular file: never followed, as
    its bytes are rewritten and cut; ``fresh``: see ``refusal``)."""
    try:
        # by the name given first (what it says), then the file it leads to (a link's folders)
        refused = refusal(shown, fresh=fresh) or refusal(log, fresh=fresh)  # OSError: cannot create
        if refused is not None:
            raise FdrOpenError(what, refused)
        make_dirs_durably(log.parent)
        fd = open_regular(lock_path(log), os.O_RDWR | os.O_CREAT)
    except NotRegularFileError as exc:
        raise FdrOpenError(what, exc.strerror or str(exc)) from exc
    except OSError as exc:
        raise FdrOpenError(what, f"cannot create: {exc.strerror or exc}") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        raise FdrOpenError(what, held_by(lock_path(log))) from exc
    return fd


def _note(line: str) -> DroppedRecords | None:
    """The note of lost records in a lock file's second line; ``None`` when it holds none (or
    something this recorder did not write: nothing to carry)."""
    try:
        fields = loads_json(line)
        count, size_bytes, first_seq, last_seq = (
            fields[k] for k in ("count", "size_bytes", "first_seq", "last_seq")
        )
        reasons = tuple(r for r in fields["reasons"] if r in (LET_GO, STOPPED))
    except (ValueError, TypeError, KeyError):
        return None
    if not all(type(n) is int and n >= 0 for n in (count, size_bytes, first_seq, last_seq)):
        return None
    return DroppedRecords(count, size_bytes, first_seq, last_seq, reasons)


class LockFile:
    """The lock file of the log whose live segment is ``log``, held (``take_lock``: ``what``,
    ``shown`` and ``fresh`` as there) and written by its recorder: its pid and, while records
    wait, their note (module docstring). ``fd`` is -1 once closed."""

    def __init__(self, log: Path, what: str, shown: Path, *, fresh: bool = False) -> None:
        self.path = lock_path(log)
        self.fd = take_lock(log, what, shown, fresh=fresh)
        self.names_loss = False  # it names records not yet in the log
        self.unwritten = False  # it lacks our bytes: a start on a full disk
        self.noted = ""  # where the last write failure's waiting records are named, or why not

    def write(self, lost: DroppedRecords | None) -> None:
        """Our pid and, while they are not yet in the log, the records ``lost`` should the
        recorder stop: written over the file's own bytes, which needs no space."""
        data = lock_text(os.getpid(), lost)
        if os.pwrite(self.fd, data, 0) != len(data):
            raise OSError(errno.EIO, "short write")
        os.ftruncate(self.fd, len(data))
        os.fsync(self.fd)
        self.names_loss = lost is not None
        self.unwritten = False

    def write_first(self, carried: DroppedRecords | None) -> None:
        """``write(carried)``, at start-up. A new lock file on a full disk has no bytes to
        write over: the recorder starts all the same (a frame never fails because of the FDR)
        and writes them once the disk takes a record. The file keeps until then the note
        ``carried`` (as it was) or nothing (freeing bytes needs no room)."""
        try:
            self.write(carried)
        except OSError:
            if carried is None:
                with contextlib.suppress(OSError):
                    os.ftruncate(self.fd, 0)
            self.names_loss = carried is not None
            self.unwritten = True

    def note_waiting(self, pending: Pending) -> None:
        """Name what waits in ``pending``, as records lost should the recorder stop before it
        writes them: the next recorder at this path gives none of their seqs again and records
        the loss. ``noted`` keeps what ``close`` adds to its error: where, or why not."""
        try:
            self.write(pending.lost())
        except OSError as exc:
            self.noted = f" (and cannot be noted in {self.path.name}: {exc.strerror or exc})"
            return
        self.noted = "; the next recorder to append to this log records them as " + RECORDS_DROPPED

    def close(self) -> None:
        """Close the file, which releases the lock (once)."""
        if self.fd >= 0:
            fd, self.fd = self.fd, -1
            os.close(fd)
