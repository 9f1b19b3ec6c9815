"""What reading or writing the sidecar of stored map features raises (the sidecar:
:mod:`c3_matcher.tilestore.sidecar`): an outage of the flight's reader, a damaged database, a
corrupt row."""

from __future__ import annotations

import sqlite3
from pathlib import Path

__all__ = ["FeatureStoreUnavailableError", "SidecarDamagedError", "StoredFeaturesCorruptError"]


class FeatureStoreUnavailableError(RuntimeError):
    """The sidecar ``path`` is locked by another process or unreadable (``why``, in words, its
    cause SQLite's error; ``fix``: what makes it readable, when something does): raised once
    per outage (the store then serves nothing until it is tried again, ``retry_s`` later)."""

    def __init__(
        self, path: Path, why: str, *, fix: str = "", retry_s: float | None = None
    ) -> None:
        self.path, self.why = path, why
        then = "" if retry_s is None else f"; extracting instead, next try in {retry_s:g} s"
        super().__init__(f"{path}: {why}{f'; {fix}' if fix else ''}{then}")


class SidecarDamagedError(RuntimeError):
    """The sidecar is not an SQLite database, or a damaged one: SQLite says so (when the writer
    opens it, or on a later read or write), or a stored value is malformed (a ``window_sets``
    row that is no feature set, a window key that is no integer). Nothing in it can be kept
    (``path``; the cause is SQLite's error or what is malformed); ``features build`` moves it
    aside and builds anew, the flight extracts instead."""

    def __init__(self, path: Path, cause: sqlite3.DatabaseError | str) -> None:
        self.path = path
        super().__init__(f"{path}: {' '.join(str(cause).split())}")


class StoredFeaturesCorruptError(RuntimeError):
    """A stored row does not match its checksum (or cannot be decoded): raised once per row,
    which is never served."""
