"""A file its reader may not open, made without root's help (fault tests run as root on CI,
where ``chmod 000`` blocks nothing): ``os.open`` refused with EACCES for that one file, what a
user without read permission gets, and ``sqlite3.connect`` failing with the CANTOPEN error
SQLite gives such a file; every other file opens as it is."""

from __future__ import annotations

import errno
import os
import sqlite3
from pathlib import Path
from typing import Any

import pytest

__all__ = ["cantopen", "refuse_reading"]


def cantopen() -> sqlite3.OperationalError:
    """The error SQLite gives for a file it may not open."""
    exc = sqlite3.OperationalError("unable to open database file")
    exc.sqlite_errorcode = sqlite3.SQLITE_CANTOPEN
    return exc


def refuse_reading(monkeypatch: pytest.MonkeyPatch, target: Path) -> None:
    """From now until ``monkeypatch`` undoes it, ``target`` opens as a file without read
    permission does, for ``os.open`` and for SQLite."""
    real_open, real_connect = os.open, sqlite3.connect

    def os_open(path: Any, flags: int, *args: Any, **kwargs: Any) -> int:
        if Path(path).resolve() == target.resolve():
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, flags, *args, **kwargs)

    def connect(database: Any, *args: Any, **kwargs: Any) -> sqlite3.Connection:
        if str(database) == str(target) or str(target.resolve()) in str(database):
            raise cantopen()
        return real_connect(database, *args, **kwargs)

    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(sqlite3, "connect", connect)
