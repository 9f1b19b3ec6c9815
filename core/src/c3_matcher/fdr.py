"""Flight-data recorder clients (C13, the shared record schema).

``JsonlFdrRecorder`` is the durable one: every record is one JSON line, flushed and fsynced
before ``record`` returns, in an append-only file rotated by size (rotated segments are kept:
nothing is ever deleted). ``InMemoryFdr`` is the test double.

Record schema (one JSON object per line)::

    {"seq": 17, "kind": "matcher.frame_done", "recorded_at_ns": 123, "wall_time": "...Z",
     "payload": {...}}
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import errno
import fcntl
import json
import math
import os
import threading
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import C3Error, InvalidInputError
from c3_matcher.protocols import Clock

__all__ = [
    "FdrOpenError",
    "FdrReadResult",
    "FdrRecord",
    "FdrWriteError",
    "InMemoryFdr",
    "JsonlFdrRecorder",
    "read_fdr",
    "to_jsonable",
]

FdrRecord = dict[str, Any]


class FdrWriteError(C3Error):
    """A record could not be made durable; it is kept pending and retried on the next record."""


class FdrOpenError(InvalidInputError):
    """The FDR cannot be opened: the path is a directory or unwritable, or another process
    already writes it (the live segment is locked with ``flock``)."""


class FdrReadResult(list[FdrRecord]):
    """The records of a segment (a list, as before) plus what could not be read: ``corrupt``
    holds ``(line_number, raw_bytes, reason)`` for every line that is not a JSON object, the
    torn last line included (``torn_tail``). Nothing is skipped silently."""

    def __init__(self) -> None:
        super().__init__()
        self.corrupt: list[tuple[int, bytes, str]] = []
        self.torn_tail: bytes | None = None

    @property
    def ok(self) -> bool:
        return not self.corrupt


def to_jsonable(value: Any) -> Any:
    """Convert DTO field values (numpy, UUID, dataclasses, paths) into JSON-native values."""
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (uuid.UUID, Path)):
        return str(value)
    if hasattr(value, "as_list"):
        return value.as_list()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return repr(value)


class InMemoryFdr:
    """Test double: keeps records in a list, in order."""

    def __init__(self) -> None:
        self.records: list[tuple[str, dict[str, Any]]] = []

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        self.records.append((kind, to_jsonable(payload)))

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        return [p for k, p in self.records if k == kind]


class JsonlFdrRecorder:
    """Durable append-only JSON Lines recorder, rotated by size, safe under power loss.

    ``path`` is the live segment; when appending would pass ``max_bytes`` it is renamed to
    ``<stem>.<NNNNNN><suffix>`` (a number above every segment ever made, kept in
    ``<path>.meta`` so that offloading old segments never reuses a number; an existing file is
    never overwritten) and a new live segment starts. ``seq`` continues across restarts,
    rotations and offloads.

    Guarantees: ``record`` returns only after the line is written and fsynced. A write failure
    (disk full, short write, I/O error) is rolled back to the last complete line, raises
    ``FdrWriteError`` and keeps the record pending; the next ``record`` writes pending records
    first, so none is dropped (``flush`` retries them without a new record; ``close`` tries
    once). A rotation is atomic with respect to failure: the next segment number is reserved in
    ``<path>.meta`` before the live segment is renamed, and if either step fails (disk full)
    nothing has moved: the recorder keeps appending to the live segment past ``max_bytes`` and
    rotates at the next record that finds room. On open, a torn last line (power cut
    mid-write) is cut back to the last complete line; the cut bytes are appended to
    ``<path>.torn`` (one JSON line per cut: offset, length, the bytes) and a
    ``fdr.torn_tail_cut`` record says so. One process
    writes a path: the recorder holds ``flock`` on ``<path>.lock``; a second one is refused
    with ``FdrOpenError``. ``record`` is thread-safe.
    """

    def __init__(self, path: Path, clock: Clock, max_bytes: int = 64 * 1024 * 1024) -> None:
        if max_bytes < 1024:
            raise InvalidInputError("fdr.max_bytes", f"must be >= 1024, got {max_bytes}")
        self._path = Path(path).expanduser()
        self._clock = clock
        self._max_bytes = max_bytes
        self._lock = threading.RLock()
        self._pending: list[bytes] = []
        self._fd = -1
        self._lock_fd = -1
        self._needs_repair = False
        self._reserved: int | None = None  # a segment number reserved by a failed rotation
        what = f"fdr.path {self._path}"
        if self._path.is_dir():
            raise FdrOpenError(what, "is a directory (give a file path)")
        try:
            self._path.parent.mkdir(parents=True, exist_ok=True)
            self._lock_fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise FdrOpenError(what, f"cannot create: {exc.strerror or exc}") from exc
        try:
            fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _read_small(self._lock_path).strip() or "?"
            os.close(self._lock_fd)
            self._lock_fd = -1
            raise FdrOpenError(
                what, f"another process (pid {holder}) is writing this FDR; one writer per path"
            ) from exc
        try:
            os.ftruncate(self._lock_fd, 0)
            os.pwrite(self._lock_fd, f"{os.getpid()}\n".encode(), 0)
            self._drop_half_rotated_live()
            torn = self._cut_torn_tail()
            self._seq = self._last_seq() + 1
            self._fd = self._open()
        except OSError as exc:
            self.close()
            raise FdrOpenError(what, f"cannot open: {exc.strerror or exc}") from exc
        if torn is not None:
            offset, length = torn
            self.record(
                "fdr.torn_tail_cut",
                {"offset": offset, "length": length, "kept_in": str(self.torn_path)},
            )

    @property
    def path(self) -> Path:
        return self._path

    @property
    def torn_path(self) -> Path:
        """Where bytes cut from torn tails are kept for the investigator."""
        return self._path.with_name(self._path.name + ".torn")

    @property
    def _lock_path(self) -> Path:
        return self._path.with_name(self._path.name + ".lock")

    @property
    def _meta_path(self) -> Path:
        return self._path.with_name(self._path.name + ".meta")

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        if not kind or not isinstance(kind, str):
            raise InvalidInputError("fdr.kind", "must be a non-empty string")
        body = to_jsonable(payload)
        with self._lock:
            if self._lock_fd < 0:
                raise FdrWriteError(f"FDR {self._path}: recorder is closed")
            line = {
                "seq": self._seq,
                "kind": kind,
                "recorded_at_ns": self._clock.monotonic_ns(),
                "wall_time": dt.datetime.now(dt.UTC).isoformat(timespec="microseconds"),
                "payload": body,
            }
            self._seq += 1
            self._pending.append((json.dumps(line, separators=(",", ":")) + "\n").encode())
            self._write_pending()

    @property
    def pending(self) -> int:
        """How many records are accepted but not yet durable (after a write failure)."""
        with self._lock:
            return len(self._pending)

    def flush(self) -> None:
        """Write the pending records now (say, once space has returned); ``FdrWriteError`` if
        they still cannot be written."""
        with self._lock:
            if self._pending and self._lock_fd < 0:
                raise FdrWriteError(f"FDR {self._path}: recorder is closed")
            self._write_pending()

    def close(self) -> None:
        with self._lock:
            if self._pending and self._lock_fd >= 0:
                with contextlib.suppress(FdrWriteError):  # a last chance after a full disk
                    self._write_pending()
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1
            if self._lock_fd >= 0:
                os.close(self._lock_fd)  # releases the flock
                self._lock_fd = -1

    def segments(self) -> list[Path]:
        """Rotated segments oldest first (by number), then the live one."""
        return [p for _, p in self._rotated()] + [self._path]

    # -- internals ------------------------------------------------------------------------
    def _write_pending(self) -> None:
        try:
            while self._pending:
                self._write_durably(self._pending[0])
                self._pending.pop(0)
        except OSError as exc:
            raise FdrWriteError(
                f"FDR {self._path}: {exc}; {len(self._pending)} record(s) pending"
            ) from exc

    def _rotated(self) -> list[tuple[int, Path]]:
        stem, suffix = self._path.stem, self._path.suffix
        out = []
        for p in self._path.parent.glob(f"{stem}.[0-9]*{suffix}"):
            number = p.name[len(stem) + 1 : len(p.name) - len(suffix)]
            if number.isdigit():
                out.append((int(number), p))
        return sorted(out)

    def _write_durably(self, data: bytes) -> None:
        if self._fd < 0:
            self._fd = self._open()
        if self._needs_repair:
            self._cut_torn_tail()
            self._needs_repair = False
        start = os.fstat(self._fd).st_size
        if start > 0 and start + len(data) > self._max_bytes and self._rotate():
            start = 0
        try:
            view = memoryview(data)
            while view:
                written = os.write(self._fd, view)
                if written <= 0:
                    raise OSError(errno.EIO, "short write")
                view = view[written:]
            os.fsync(self._fd)
        except OSError:
            try:  # roll back to the last complete line, so the retry is not glued to a fragment
                os.ftruncate(self._fd, start)
                os.fsync(self._fd)
            except OSError:
                self._needs_repair = True
            raise

    def _open(self) -> int:
        return os.open(self._path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def _next_segment_number(self) -> int:
        numbers = [n for n, _ in self._rotated()]
        meta = _read_meta(self._meta_path)
        return max([0, *numbers, int(meta.get("last_segment", 0))]) + 1

    def _rotate(self) -> bool:
        """Start a new live segment. ``False`` when nothing could be moved (the number could
        not be reserved or the rename failed, say on a full disk): the caller keeps appending
        to the live segment. After the rename an error propagates with ``_fd`` closed, so the
        next write opens the new live segment: the rotation is then complete either way."""
        number = self._reserved or self._next_segment_number()
        target = self._path.with_name(f"{self._path.stem}.{number:06d}{self._path.suffix}")
        while target.exists():  # never overwrite (we hold the lock: no other writer races us)
            number += 1
            target = self._path.with_name(f"{self._path.stem}.{number:06d}{self._path.suffix}")
        try:  # reserve the number first: a failure here leaves everything as it was
            if number != self._reserved:
                _write_meta(self._meta_path, {"last_segment": number, "last_seq": self._seq - 1})
                self._reserved = number  # kept for the next try: one number per rotation
            self._path.rename(target)  # atomic: the records are under exactly one name
        except OSError:
            return False  # at worst a reserved number stays unused: never a reused one
        self._reserved = None
        os.close(self._fd)
        self._fd = -1
        self._fd = self._open()
        _fsync_dir(self._path.parent)
        return True

    def _drop_half_rotated_live(self) -> None:
        """Should the live segment and the newest rotated one be one file under two names (a
        rotation by hard link interrupted), drop the live name: the rotated one keeps the data."""
        if not self._path.exists():
            return
        live = self._path.stat()
        for _, p in self._rotated()[-1:]:
            st = p.stat()
            if (st.st_dev, st.st_ino) == (live.st_dev, live.st_ino):
                self._path.unlink()
                _fsync_dir(self._path.parent)

    def _cut_torn_tail(self) -> tuple[int, int] | None:
        """Cut the live segment back to its last complete line; keep the cut bytes aside."""
        if not self._path.exists():
            return None
        with self._path.open("r+b") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size == 0:
                return None
            fh.seek(max(0, size - 1))
            if fh.read(1) == b"\n":
                return None
            keep = 0
            block = 1 << 16
            pos = size
            while pos > 0:  # find the last newline, reading backwards
                lo = max(0, pos - block)
                fh.seek(lo)
                chunk = fh.read(pos - lo)
                i = chunk.rfind(b"\n")
                if i >= 0:
                    keep = lo + i + 1
                    break
                pos = lo
            fh.seek(keep)
            cut = fh.read()
            side = {
                "segment": self._path.name,
                "offset": keep,
                "length": len(cut),
                "cut_at_wall_time": dt.datetime.now(dt.UTC).isoformat(timespec="microseconds"),
                "bytes": cut.decode("utf-8", "backslashreplace"),
            }
            with self.torn_path.open("ab") as side_fh:
                side_fh.write((json.dumps(side) + "\n").encode())
                side_fh.flush()
                os.fsync(side_fh.fileno())
            fh.truncate(keep)
            fh.flush()
            os.fsync(fh.fileno())
        return keep, len(cut)

    def _last_seq(self) -> int:
        last = int(_read_meta(self._meta_path).get("last_seq", 0))
        rotated = self._rotated()
        for p in [*(q for _, q in rotated[-1:]), self._path]:
            if p.exists():
                for record in read_fdr(p):
                    seq = record.get("seq", 0) if isinstance(record, dict) else 0
                    if isinstance(seq, int):
                        last = max(last, seq)
        return last


def _read_small(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")[:64]
    except OSError:
        return ""


def _read_meta(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write_meta(path: Path, data: Mapping[str, Any]) -> None:
    """Atomically replace the small state file (never a segment)."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("wb") as fh:
            fh.write(json.dumps(dict(data)).encode())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)  # give back what a full disk let us take
        raise


def _fsync_dir(directory: Path) -> None:
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def read_fdr(path: Path) -> FdrReadResult:
    """Read every record of an FDR segment. The result is a list of the records; lines that
    are not complete JSON objects are reported in ``.corrupt`` (a torn last line also in
    ``.torn_tail``), never skipped silently."""
    result = FdrReadResult()
    with Path(path).open("rb") as fh:
        for number, raw in enumerate(fh, start=1):
            if not raw.endswith(b"\n"):
                result.torn_tail = raw
                result.corrupt.append((number, raw, "torn last line (no newline)"))
                break
            try:
                value = json.loads(raw)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                result.corrupt.append((number, raw, f"not JSON: {exc}"))
                continue
            if not isinstance(value, dict):
                result.corrupt.append((number, raw, "not a JSON object"))
                continue
            result.append(value)
    return result
