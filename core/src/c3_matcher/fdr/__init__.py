"""Flight-data recorder clients (C13, the shared record schema).

``JsonlFdrRecorder`` is the durable one: every record is one JSON line, flushed and fsynced
before ``record`` returns, in an append-only file rotated by size (rotated segments are kept:
nothing is ever deleted, unless a recorder is opened with ``fresh=True``, as a ground run's is,
to start a new log under its lock). ``InMemoryFdr`` is the test double. ``read_fdr_log`` reads
every segment of a log in order; ``check_fdr`` says whether it is whole.

Record schema (one JSON object per line)::

    {"seq": 17, "kind": "matcher.frame_done", "recorded_at_ns": 123, "wall_time": "...+00:00",
     "payload": {...}}
"""

from __future__ import annotations

from c3_matcher.fdr.check import FdrCheck, check_fdr, read_fdr_log
from c3_matcher.fdr.jsonl import JsonlFdrRecorder
from c3_matcher.fdr.records import (
    FdrOpenError,
    FdrReadResult,
    FdrRecord,
    FdrWriteError,
    InMemoryFdr,
    read_fdr,
    to_jsonable,
)

__all__ = [
    "FdrCheck",
    "FdrOpenError",
    "FdrReadResult",
    "FdrRecord",
    "FdrWriteError",
    "InMemoryFdr",
    "JsonlFdrRecorder",
    "check_fdr",
    "read_fdr",
    "read_fdr_log",
    "to_jsonable",
]
