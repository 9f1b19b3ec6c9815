"""Moving the live segment aside (a rotation), and the warning a rotation that fails gives.

A rotation reserves the next segment number in ``.meta`` before it renames the live segment,
so a failure of either step (a full disk, a directory that became unwritable) moves nothing:
the recorder keeps appending to the live segment, past ``max_bytes``, and tries again at the
next record. That the log no longer rotates is said once per outage, not once per record: the
first rotation that fails makes one WARNING ``ROTATE_FAILED`` (naming the error, the segment
and its size), the next ones say nothing until a rotation succeeds again.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from loguru import logger

from c3_matcher.errors import describe
from c3_matcher.fdr.files import meta_path, read_meta, rotated_segments, segment_path, write_meta

ROTATE_FAILED = "c3.fdr.rotate_failed"
"""The kind of the WARNING a rotation that failed logs (once until one succeeds again)."""


@dataclass(frozen=True, slots=True)
class RotateFailure:
    """A rotation that failed: the live ``segment``, its ``size`` in bytes, the ``error``."""

    segment: Path
    size: int
    error: str

    def log(self) -> None:
        """The one WARNING of this outage. Logged by the recorder once its lock is released:
        the logs' forwarder writes the warning to the FDR, maybe this very recorder."""
        logger.bind(
            kind=ROTATE_FAILED, segment=str(self.segment), size=self.size, error=self.error
        ).warning(
            f"FDR segment {self.segment} not rotated at {self.size} bytes ({self.error}): "
            "records go on to it, past max_bytes, until a rotation succeeds"
        )


class Rotation:
    """The rotations of the live segment ``path``: a number is never reused (one is reserved
    per rotation, kept across failed tries), and a failure is said once per outage."""

    def __init__(self, path: Path) -> None:
        self._path = path
        self._reserved: int | None = None  # a segment number reserved by a failed rotation
        self._failing = False  # the last rotation failed: its outage is said already
        self._unsaid: RotateFailure | None = None  # a failure not yet logged

    def next_number(self) -> int:
        """A number above every rotated segment there is and every one ``.meta`` reserved."""
        numbers = [n for n, _ in rotated_segments(self._path)]
        meta = read_meta(meta_path(self._path))
        return max([0, *numbers, int(meta.get("last_segment", 0))]) + 1

    def move_aside(self, last_seq: int, size: int) -> bool:
        """Rename the live segment (``size`` bytes) to the next rotated segment, after keeping
        its number and ``last_seq`` in ``.meta``. ``False`` when nothing could be moved: the
        first failure of an outage is kept for ``take_failure``."""
        number = self._reserved or self.next_number()
        while os.path.lexists(segment_path(self._path, number)):  # never overwrite (ours: locked)
            number += 1
        try:  # reserve the number first: a failure here leaves everything as it was
            write_meta(meta_path(self._path), {"last_segment": number, "last_seq": last_seq})
            self._reserved = number  # kept for the next try: one number per rotation
            self._path.rename(segment_path(self._path, number))  # atomic: one name per record
        except OSError as exc:  # at worst a reserved number stays unused: never a reused one
            if not self._failing:
                self._failing = True
                self._unsaid = RotateFailure(self._path, size, describe(exc))
            return False
        self._reserved = None
        self._failing = False
        return True

    def take_failure(self) -> RotateFailure | None:
        """The failure not yet logged, if any (taken: it is logged once)."""
        unsaid, self._unsaid = self._unsaid, None
        return unsaid
