"""Shared fixtures of the core's tests."""

from __future__ import annotations

import io
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.logs import configure_logging


class LogCapture:
    """Structured log records written by the JSON sink, parsed back."""

    def __init__(self, stream: io.StringIO) -> None:
        self._stream = stream

    @property
    def records(self) -> list[dict[str, Any]]:
        return [json.loads(line) for line in self._stream.getvalue().splitlines() if line]

    def of_kind(self, kind: str) -> list[dict[str, Any]]:
        return [r for r in self.records if r["kind"] == kind]


@pytest.fixture
def fdr() -> InMemoryFdr:
    return InMemoryFdr()


@pytest.fixture
def logs(fdr: InMemoryFdr) -> Iterator[LogCapture]:
    stream = io.StringIO()
    handle = configure_logging(fdr, level="DEBUG", stream=stream)
    yield LogCapture(stream)
    handle.close()


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> pytest.MonkeyPatch:
    """No ``C3_MATCHER_`` variable of the caller's, and the FDR in ``tmp_path`` (the default
    path would be shared by tests running side by side); returns ``monkeypatch``."""
    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    return monkeypatch
