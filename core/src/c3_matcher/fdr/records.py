"""The FDR record format: JSON conversion of payloads, reading a segment back, the in-memory
recorder (the test double) and the recorder errors."""

from __future__ import annotations

import dataclasses
import math
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import C3Error, InvalidInputError
from c3_matcher.json_text import loads_json

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


def read_fdr(path: Path) -> FdrReadResult:
    """Read every record of an FDR segment. The result is a list of the records; lines that
    are not complete JSON objects (nested too deep or holding a number too long to read
    included) are reported in ``.corrupt`` (a torn last line also in ``.torn_tail``), never
    skipped silently."""
    result = FdrReadResult()
    with Path(path).open("rb") as fh:
        for number, raw in enumerate(fh, start=1):
            if not raw.endswith(b"\n"):
                result.torn_tail = raw
                result.corrupt.append((number, raw, "torn last line (no newline)"))
                break
            try:
                value = loads_json(raw)
            except ValueError as exc:  # not JSON, not UTF-8, too deep, too many digits
                result.corrupt.append((number, raw, f"not JSON: {exc}"))
                continue
            if not isinstance(value, dict):
                result.corrupt.append((number, raw, "not a JSON object"))
                continue
            result.append(value)
    return result
