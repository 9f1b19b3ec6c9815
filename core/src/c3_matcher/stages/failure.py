"""The typed failure of a candidate's backbone step and the timing of a step."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

from c3_matcher.errors import describe
from c3_matcher.stages.interrupts import is_stop

__all__ = ["CandidateStepError", "failing_as", "timed"]


class CandidateStepError(Exception):
    """A candidate's backbone step failed, so the candidate is dropped (drop and continue).

    ``phase`` names the step (``tile_decode``, the backend's extract or match phase,
    ``ransac``); ``source`` is where the candidate's features came or were to come from
    (``none`` before that was known, else ``stored``, ``cached`` or ``extracted``); ``cause``
    is the exception the step raised (a plugin's own ``BaseException`` too: ``failing_as``)."""

    def __init__(self, phase: str, source: str, cause: BaseException) -> None:
        super().__init__(f"{phase}: {describe(cause)}")
        self.phase = phase
        self.source = source
        self.cause = cause


@contextmanager
def failing_as(phase: str, source: str) -> Iterator[None]:
    """Run a step of a candidate: any exception it raises leaves as a ``CandidateStepError`` of
    ``phase`` (features from ``source``), a plugin's own ``BaseException`` too (it fails the
    step, not the flight); a stop (Ctrl-C, a signal handler's exit, a closing generator) goes on
    (``stages.interrupts.is_stop``)."""
    try:
        yield
    except BaseException as exc:
        if is_stop(exc):
            raise
        raise CandidateStepError(phase, source, exc) from exc


@contextmanager
def timed(into: dict[str, float], name: str) -> Iterator[None]:
    """Add the wall time of the block (ms, ``time.perf_counter``) to ``into[name]``, also when
    it raises."""
    start = time.perf_counter()
    try:
        yield
    finally:
        into[name] = into.get(name, 0.0) + (time.perf_counter() - start) * 1e3
