"""Why a matcher dropped each candidate of a call, heard from its log events while the call
runs: for a caller that says it beside the result (``c3-matcher match``'s ``dropped``, a run's
summary). The words are those of the FDR's terminal records (:func:`drop_reason`)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from loguru import logger

from c3_matcher.stages.recorder import drop_reason

__all__ = ["HeardDrop", "drops_heard"]


@dataclass(frozen=True)
class HeardDrop:
    """One candidate dropped: its input position, why (in words) and the fields of the log
    event that dropped it (``kind``, ``tile_id``, ``phase``, ``error``, ...)."""

    index: int
    reason: str
    event: Mapping[str, Any]


@contextlib.contextmanager
def drops_heard() -> Iterator[dict[int, HeardDrop]]:
    """The candidates dropped while the block runs, by input position (two candidates may
    share a tile id): a backbone error, no inlier, or a refusal on geometry."""
    heard: dict[int, HeardDrop] = {}

    def sink(message: Any) -> None:
        extra = message.record["extra"]
        index, reason = extra.get("candidate_index"), drop_reason(extra.get("kind"), extra)
        if index is not None and reason is not None:
            heard[int(index)] = HeardDrop(int(index), reason, dict(extra))

    listening = logger.add(sink, level="DEBUG", format="{message}")
    try:
        yield heard
    finally:
        with contextlib.suppress(ValueError):
            logger.remove(listening)
