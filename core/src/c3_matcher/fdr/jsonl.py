"""``JsonlFdrRecorder``: the durable flight-data recorder, one fsynced JSON line a record."""

from __future__ import annotations

import contextlib
import datetime as dt
import errno
import json
import os
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from c3_matcher.clocks import SteadyClock
from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr.files import (
    RECORD_KEYS,
    cut_torn_tail,
    drop_half_rotated_live,
    live_segment,
    meta_path,
    open_for_append,
    read_meta,
    remove_log,
    rotated_segments,
)
from c3_matcher.fdr.forks import close_copies, forked_from
from c3_matcher.fdr.moved import (
    SEGMENT_REPLACED,
    SegmentReplaced,
    keep_last_seq,
    new_name,
    reopen_live,
    still_there,
)
from c3_matcher.fdr.pending import RECORDS_DROPPED, LockFile, Pending, read_lock
from c3_matcher.fdr.records import FdrOpenError, FdrWriteError, to_jsonable
from c3_matcher.fdr.rotation import Rotation
from c3_matcher.fdr.tail import recent_seqs
from c3_matcher.fdr.turns import close_after_frame
from c3_matcher.protocols import Clock

SEGMENT_BYTES = 64 * 1024 * 1024
"""Default ``max_bytes``: a live segment rotates above this size."""
PENDING_BYTES = 64 * 1024 * 1024
"""Default ``max_pending_bytes``: what records may wait while the disk is full."""
MIN_BYTES = 1024
"""The least either bound may be."""


class JsonlFdrRecorder:
    """Durable append-only JSON Lines recorder, rotated by size, safe under power loss.

    ``path`` is the live segment; when appending would pass ``max_bytes`` it is renamed to
    ``<stem>.<NNNNNN><suffix>`` (a number above every segment ever made, kept in
    ``<path>.meta`` so that offloading old segments never reuses a number; an existing file is
    never overwritten) and a new live segment starts. ``seq`` continues across restarts,
    rotations and offloads.

    Guarantees: ``record`` returns only after the line is written and fsynced (and, for a
    segment or directory it created, their directory entries). A write failure (disk full,
    short write, I/O error) is rolled back to the last complete line, raises ``FdrWriteError``
    and keeps the record pending; the next ``record`` writes pending records first, so none is
    dropped (``flush`` retries them without a new record; ``close`` tries once more and raises
    ``FdrWriteError`` for what it could not write). While records wait they are named in the
    lock file, in bytes it already has: should the recorder stop before writing them (closed,
    killed, out of power), the next recorder at ``path`` gives none of their seqs again and
    says they were lost in a ``fdr.records_dropped`` record. A rotation is atomic with respect to
    failure: the next segment number is reserved in ``<path>.meta`` before the live segment is
    renamed, and if either step fails (disk full) nothing has moved: the recorder keeps
    appending to the live segment past ``max_bytes`` and rotates at the next record that finds
    room (one WARNING ``c3.fdr.rotate_failed`` says so, until a rotation succeeds: ``rotation``).
    A write the file system refuses as too large (EFBIG: a file-size limit below ``max_bytes``,
    a FAT32 card's 4 GiB or ``RLIMIT_FSIZE``) rotates a live segment that has records and is
    tried once more in the new one. On open, a torn last line (power cut mid-write) is cut back
    to the last complete line; the cut bytes are appended to ``<path>.torn`` (one JSON line per
    cut: offset, length, the bytes) and a ``fdr.torn_tail_cut`` record says so (kept pending,
    like any record, when it cannot be written yet). On a full disk the cut bytes are dropped,
    being part of no acknowledged record, and that record says why. What waits is bounded by
    ``max_pending_bytes``, so a disk that stays full cannot exhaust the vehicle's memory: past
    it the oldest waiting records are let go (the newest say the most about the vehicle's state
    now), and once the rest are written a ``fdr.records_dropped`` record says how many and
    which seqs (the only gap ``seq`` ever has). One process writes a log: the recorder
    holds ``flock`` on ``<path>.lock``, ``path`` being the file the name given leads to
    (``live_segment``: links resolved, as for every file of the log; messages say the name
    given); a second one, by any name, is refused with ``FdrOpenError``, as is a
    ``path`` holding something else (not empty, not all NUL bytes, its first line not a record
    nor a record's start cut by a power cut: an image or a JSON document named by mistake),
    which is never cut, appended to or removed, or that is not a regular file (a device, a
    FIFO, a socket: never opened). A start on a full disk with no lock file yet starts all the
    same; the lock file gets its bytes with the first write the disk takes (until then a loss
    it would name cannot be noted, which ``close`` says). A live segment of NUL bytes alone (a
    power cut during its first line, on a file system that had committed the size but not the
    data) is a torn tail, cut as one. ``record`` is thread-safe, and refused in a forked child.
    A live segment removed or renamed while open (``rm``, a ``logrotate`` ``mv``) is made anew
    at the next record or at ``close``, ``seq`` going on, and said once (``moved``).
    ``recorded_at_ns`` is always an ``int`` >= 0, whatever the clock gives (``SteadyClock``).

    ``fresh``: start a new log at ``path`` (a ground run's FDR, started anew with each run):
    only once the lock is held are the previous live segment, its rotated segments, ``.meta``
    and ``.torn`` removed, so a recorder refused by the lock leaves another writer's files as
    they are; ``seq`` then starts at 1. A link at ``path`` is then one of those files: removed,
    never followed (``live_segment``).
    """

    def __init__(
        self,
        path: Path,
        clock: Clock,
        max_bytes: int = SEGMENT_BYTES,
        *,
        max_pending_bytes: int = PENDING_BYTES,
        fresh: bool = False,
    ) -> None:
        for name, value in (("max_bytes", max_bytes), ("max_pending_bytes", max_pending_bytes)):
            if value < MIN_BYTES:
                raise InvalidInputError(f"fdr.{name}", f"must be >= {MIN_BYTES}, got {value}")
        self._shown = Path(path).expanduser()  # the name given: what messages say
        self._path = live_segment(self._shown, fresh=fresh)  # where the log's files are
        self._pid = os.getpid()  # a fork's child writes nothing: refused before ``_lock``
        self._clock = SteadyClock.of(clock)
        self._max_bytes = max_bytes
        self._lock = threading.RLock()
        self._pending = Pending(max_pending_bytes)
        self._fd = -1
        self._repair_to: int | None = None  # where a write that could not be rolled back began
        self._rotation = Rotation(self._path)
        self._moved: SegmentReplaced | None = None  # the live segment went: its record waits
        self._unsaid_move: SegmentReplaced | None = None  # its WARNING, not yet logged
        what = f"fdr.path {self._shown}"
        self._lockfile = LockFile(self._path, what, self._shown, fresh=fresh)
        try:
            carried = None if fresh else read_lock(self._lockfile.path)[1]
            if fresh:
                remove_log(self._path, self.torn_path)
            drop_half_rotated_live(self._path)
            torn = cut_torn_tail(self._path, self.torn_path)
            seqs = recent_seqs(self._path, carried.first_seq if carried else None)
            self._seq = max([self._meta_seq(), *seqs, carried.last_seq if carried else 0]) + 1
            carried = carried and carried.without(seqs)  # some written before the last stopped
            self._lockfile.write_first(carried)  # the note of records lost when the last stopped
            self._fd = open_for_append(self._path)
            self._pending.dropped = carried
        except OSError as exc:
            self._close()
            raise FdrOpenError(what, f"cannot open: {exc.strerror or exc}") from exc
        with contextlib.suppress(FdrWriteError):  # kept pending: the next record writes them
            if torn is None:
                with self._locked():  # the note of records lost when the last stopped, if any
                    self._write_pending()
            else:
                kept = {"kept_in": None, "not_kept": torn.not_kept} if torn.not_kept else {}
                self.record(
                    "fdr.torn_tail_cut",
                    {
                        "offset": torn.offset,
                        "length": torn.length,
                        "kept_in": str(self.torn_path),
                        **kept,
                    },
                )

    @property
    def path(self) -> Path:
        """The live segment: the file the name given leads to (links resolved)."""
        return self._path

    @property
    def torn_path(self) -> Path:
        """Where bytes cut from torn tails are kept for the investigator."""
        return self._path.with_name(self._path.name + ".torn")

    @property
    def _meta_path(self) -> Path:
        return meta_path(self._path)

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        if not kind or not isinstance(kind, str):
            raise InvalidInputError("fdr.kind", "must be a non-empty string")
        self._refuse_forked()
        body = to_jsonable(payload)
        with self._locked():
            if self._lockfile.fd < 0:
                raise FdrWriteError(f"FDR {self._shown}: recorder is closed")
            self._pending.hold(self._seq, self._line(kind, body))
            self._seq += 1
            self._write_pending()

    def _line(self, kind: str, body: Any) -> bytes:
        """The record ``kind`` as one JSON line, with the next ``seq``: its ``RECORD_KEYS`` in
        order (a file is judged a log by them)."""
        wall_time = dt.datetime.now(dt.UTC).isoformat(timespec="microseconds")
        values = (self._seq, kind, self._clock.monotonic_ns(), wall_time, body)
        line = dict(zip(RECORD_KEYS, values, strict=True))
        return (json.dumps(line, separators=(",", ":")) + "\n").encode()

    @property
    def pending(self) -> int:
        """How many records are accepted but not yet durable (after a write failure)."""
        with self._lock:
            return len(self._pending.records)

    @property
    def dropped(self) -> int:
        """How many waiting records were let go since this recorder opened (a disk full for
        longer than ``max_pending_bytes`` of records)."""
        with self._lock:
            return self._pending.dropped_total

    def flush(self) -> None:
        """Write the pending records now (say, once space has returned); ``FdrWriteError`` if
        they still cannot be written."""
        self._refuse_forked()
        with self._locked():
            if self._pending.waiting and self._lockfile.fd < 0:
                raise FdrWriteError(f"FDR {self._shown}: recorder is closed")
            self._write_pending()

    def close(self) -> None:
        """Write what is pending (a last chance after a full disk) and give the path back;
        ``FdrWriteError`` naming how many records were lost when that last write failed (the
        files are closed and the lock released all the same). Called on a thread inside a
        matcher's frame (a signal handler's shutdown), it closes once that frame is done. In a
        fork's child, at once: its copies of the files only, no lock waited for (``forks``)."""
        if forked_from(self._pid) is not None or not close_after_frame(self._close):
            self._close()

    def _close(self) -> None:
        if forked_from(self._pid) is not None:  # the parent's lock, log and records stay its own
            fds, (self._fd, self._lockfile.fd) = (self._fd, self._lockfile.fd), (-1, -1)
            close_copies(*fds)
            return
        with self._locked():
            lost: FdrWriteError | None = None
            if self._pending.waiting and self._lockfile.fd >= 0:
                try:
                    self._write_pending()
                except FdrWriteError as exc:
                    lost = exc  # its failure already named the waiting records (noted)
            if lost is None and self._lockfile.fd >= 0:
                self._say_move()
            if self._fd >= 0:
                if not still_there(self._fd, self._path):  # gone since: no seq is given again
                    keep_last_seq(self._meta_path, self._seq - 1)
                os.close(self._fd)
                self._fd = -1
            self._lockfile.close()  # releases the flock
        if lost is not None:
            raise FdrWriteError(
                f"{lost}: lost, the recorder is closed{self._lockfile.noted}"
            ) from lost

    def _say_move(self) -> None:
        """At close, a live segment removed or renamed since the last write is said as a write
        says it (``_follow_path``): a ``SEGMENT_REPLACED`` record in a new segment at ``path``.
        Should that fail (a full disk, the path taken), ``.meta`` keeps the last seq given."""
        with contextlib.suppress(OSError, FdrWriteError):
            if self._fd >= 0 and not still_there(self._fd, self._path):
                self._follow_path()
            if self._moved is not None:
                self._write_pending()

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        """Hold the recorder's lock; a rotation failure, a live segment gone or a clock problem
        seen meanwhile is logged once it is released (the logs' forwarder may write that
        warning to this very recorder)."""
        said: tuple[Any, ...] = ()
        try:
            with self._lock:
                try:
                    yield
                finally:
                    moved, self._unsaid_move = self._unsaid_move, None
                    said = (self._rotation.take_failure(), moved, self._clock.take_problem())
        finally:
            for warning in said:
                if warning is not None:
                    warning.log()

    def _refuse_forked(self) -> None:
        if (refused := forked_from(self._pid)) is not None:
            raise FdrWriteError(f"FDR {self._shown}: not written, {refused}")

    def segments(self) -> list[Path]:
        """Rotated segments oldest first (by number), then the live one."""
        return [p for _, p in self._rotated()] + [self._path]

    # -- internals ------------------------------------------------------------------------
    def _write_pending(self) -> None:
        """Write the waiting records in order, then the note of any that were let go (its seq
        is the next one: ``seq`` never goes back in the file)."""
        pending = self._pending
        try:
            while pending.records:
                self._write_durably(pending.records[0][1])
                pending.written()
            if pending.dropped is not None:
                self._write_durably(self._line(RECORDS_DROPPED, pending.dropped.payload()))
                self._seq += 1
                pending.dropped = None
            if (moved := self._moved) is not None:  # said in the segment made anew
                self._write_durably(self._line(SEGMENT_REPLACED, moved.payload()))
                self._seq += 1
                self._moved = None if self._moved is moved else self._moved
            if self._lockfile.names_loss:
                self._lockfile.write(None)  # the log says it now
        except OSError as exc:
            self._lockfile.note_waiting(pending)  # should the recorder stop now, the next knows
            let_go = f", {pending.dropped.count} let go" if pending.dropped else ""
            raise FdrWriteError(
                f"FDR {self._shown}: {exc}; {len(pending.records)} record(s) pending{let_go}"
            ) from exc
        if self._lockfile.unwritten:  # a start on a full disk: now that a record found room
            with contextlib.suppress(OSError):  # else tried again with the next record
                self._lockfile.write(None)

    def _rotated(self) -> list[tuple[int, Path]]:
        return rotated_segments(self._path)

    def _write_durably(self, data: bytes) -> None:
        """Append ``data`` to the live segment, rotating it first when ``data`` would take it
        past ``max_bytes``, or when the file system refuses it more bytes (EFBIG): then the
        write is tried once more in the new segment (a failure there is handled as any)."""
        if self._fd < 0:
            self._fd = reopen_live(self._path, self.torn_path)
        elif not still_there(self._fd, self._path):  # removed or renamed by someone else
            self._follow_path()
        if self._repair_to is not None:  # the unacknowledged line goes, whole or not
            cut_torn_tail(self._path, self.torn_path, self._repair_to)
            self._repair_to = None
        start = os.fstat(self._fd).st_size
        if start > 0 and start + len(data) > self._max_bytes and self._rotate():
            start = 0
        try:
            self._append(data, start)
        except OSError as exc:  # a segment of records too large for its file system: a new one
            too_large = exc.errno == errno.EFBIG and start > 0 and self._repair_to is None
            if not (too_large and self._rotate()):
                raise
            self._append(data, 0)

    def _append(self, data: bytes, start: int) -> None:
        """Write ``data`` at the end of the live segment (``start`` bytes) and fsync it; on a
        failure roll back to ``start``, the last complete line, so the retry is not glued to a
        fragment (``_repair_to`` says where, when even that fails), and raise."""
        try:
            view = memoryview(data)
            while view:
                written = os.write(self._fd, view)
                if written <= 0:
                    raise OSError(errno.EIO, "short write")
                view = view[written:]
            os.fsync(self._fd)
        except OSError:
            try:
                os.ftruncate(self._fd, start)
                os.fsync(self._fd)
            except OSError:
                self._repair_to = start
            raise

    def _rotate(self) -> bool:
        """Start a new live segment. ``False`` when nothing could be moved (the number could
        not be reserved or the rename failed, say on a full disk): the caller keeps appending
        to the live segment. After the rename an error propagates with ``_fd`` closed, so the
        next write opens the new live segment: the rotation is then complete either way."""
        if not self._rotation.move_aside(self._settled_seq(), os.fstat(self._fd).st_size):
            return False
        os.close(self._fd)
        self._fd = -1
        self._fd = open_for_append(self._path)  # fsyncs the directory: the rename too
        return True

    def _settled_seq(self) -> int:
        """The last seq given to a record acknowledged, or let go and so noted: never one that
        waits (a kill before it is written must leave no gap that no note explains)."""
        waiting = self._pending.records
        return waiting[0][0] - 1 if waiting else self._seq - 1

    def _follow_path(self) -> None:
        """The live segment no longer names the file written (``moved``): a new one at ``path``
        takes the records on; the records up to ``_settled_seq`` stay with the file that went."""
        moved = SegmentReplaced(self._shown, new_name(self._fd, self._path), self._settled_seq())
        os.close(self._fd)
        self._fd, self._repair_to = -1, None  # a line to cut lies in the file that went
        self._moved = self._unsaid_move = moved
        keep_last_seq(self._meta_path, moved.last_seq)
        self._fd = reopen_live(self._path, self.torn_path)

    def _meta_seq(self) -> int:
        """The last seq ``.meta`` keeps (so seq never goes back once all is offloaded)."""
        return int(read_meta(self._meta_path).get("last_seq", 0))
