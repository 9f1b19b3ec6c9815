"""Shared fixtures of the core's tests."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
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
