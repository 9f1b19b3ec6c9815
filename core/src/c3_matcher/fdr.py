"""Flight-data recorder clients (C13, AZ-272 record schema).

``JsonlFdrRecorder`` is the durable one: every record is one JSON line, flushed and fsynced
before ``record`` returns, in an append-only file rotated by size (rotated segments are kept:
nothing is ever deleted). ``InMemoryFdr`` is the test double.

Record schema (one JSON object per line)::

    {"seq": 17, "kind": "matcher.frame_done", "recorded_at_ns": 123, "wall_time": "...Z",
     "payload": {...}}
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import math
import os
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import C3Error, InvalidInputError
from c3_matcher.protocols import Clock

__all__ = [
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
    """Durable append-only JSON Lines recorder, rotated by size.

    ``path`` is the live segment; when appending would pass ``max_bytes`` it is renamed to
    ``<stem>.<NNNNNN><suffix>`` (numbered upwards, never deleted) and a new live segment starts.
    A write failure (disk full, I/O error) raises ``FdrWriteError`` and keeps the record pending;
    the next ``record`` writes pending records first, so none is dropped.
    """

    def __init__(self, path: Path, clock: Clock, max_bytes: int = 64 * 1024 * 1024) -> None:
        if max_bytes < 1024:
            raise InvalidInputError("fdr.max_bytes", f"must be >= 1024, got {max_bytes}")
        self._path = Path(path)
        self._clock = clock
        self._max_bytes = max_bytes
        self._path.parent.mkdir(parents=True, exist_ok=True)
        self._seq = self._last_seq() + 1
        self._pending: list[bytes] = []
        self._fd = self._open()

    @property
    def path(self) -> Path:
        return self._path

    def record(self, kind: str, payload: Mapping[str, Any]) -> None:
        if not kind:
            raise InvalidInputError("fdr.kind", "must be a non-empty string")
        line = {
            "seq": self._seq,
            "kind": kind,
            "recorded_at_ns": self._clock.monotonic_ns(),
            "wall_time": dt.datetime.now(dt.UTC).isoformat(timespec="microseconds"),
            "payload": to_jsonable(payload),
        }
        self._seq += 1
        self._pending.append((json.dumps(line, separators=(",", ":")) + "\n").encode())
        try:
            while self._pending:
                self._write_durably(self._pending[0])
                self._pending.pop(0)
        except OSError as exc:
            raise FdrWriteError(
                f"FDR {self._path}: {exc}; {len(self._pending)} record(s) pending"
            ) from exc

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def segments(self) -> list[Path]:
        """Rotated segments oldest first, then the live one."""
        rotated = sorted(self._path.parent.glob(f"{self._path.stem}.[0-9]*{self._path.suffix}"))
        return [*rotated, self._path]

    def _write_durably(self, data: bytes) -> None:
        if self._fd < 0:
            self._fd = self._open()
        if os.fstat(self._fd).st_size + len(data) > self._max_bytes:
            self._rotate()
        view = memoryview(data)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        os.fsync(self._fd)

    def _open(self) -> int:
        return os.open(self._path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def _rotate(self) -> None:
        os.close(self._fd)
        self._fd = -1
        index = len(self.segments())  # live segment counted: next free number
        target = self._path.with_name(f"{self._path.stem}.{index:06d}{self._path.suffix}")
        os.replace(self._path, target)
        self._fd = self._open()
        dir_fd = os.open(self._path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)

    def _last_seq(self) -> int:
        if not self._path.exists():
            return 0
        last = 0
        for record in read_fdr(self._path):
            last = max(last, int(record.get("seq", 0)))
        return last


def read_fdr(path: Path) -> Iterator[FdrRecord]:
    """Read every complete record of an FDR segment; a torn last line (power cut) is skipped."""
    with Path(path).open("rb") as fh:
        for raw in fh:
            if not raw.endswith(b"\n"):
                break
            try:
                yield json.loads(raw)
            except json.JSONDecodeError:
                continue
