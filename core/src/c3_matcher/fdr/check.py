"""A flight-data log checked after the flight: every segment read in order, ``seq`` followed
from record to record, each gap held against the recorder's notes (``fdr.records_dropped``:
records it let go; ``fdr.segment_replaced``: a live segment another program removed or renamed,
its records with it), and the lock file's note of records not yet in the log."""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import itertools
from collections import Counter
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr.files import live_segment, rotated_segments
from c3_matcher.fdr.moved import SEGMENT_REPLACED
from c3_matcher.fdr.pending import RECORDS_DROPPED, DroppedRecords, lock_path, read_lock
from c3_matcher.fdr.records import FdrRecord, read_fdr
from c3_matcher.file_kinds import special_kind

__all__ = ["FdrCheck", "MovedSegment", "SeqRange", "check_fdr", "read_fdr_log"]


@dataclasses.dataclass(frozen=True, slots=True)
class SeqRange:
    """The seqs ``first``..``last``, both included."""

    first: int
    last: int

    def __str__(self) -> str:
        return str(self.first) if self.first == self.last else f"{self.first}..{self.last}"

    def within(self, ranges: tuple[SeqRange, ...]) -> bool:
        """Every seq of this range lies in one of ``ranges``."""
        reached = self.first  # the first seq not yet covered
        for r in sorted(ranges, key=lambda r: r.first):
            if r.first > reached:
                break
            reached = max(reached, r.last + 1)
        return reached > self.last


@dataclasses.dataclass(frozen=True, slots=True)
class MovedSegment:
    """A live segment another program removed or renamed under its recorder, as the recorder's
    ``fdr.segment_replaced`` note says: the file ``segment`` named is ``moved_to`` now (None:
    removed, or moved out of its folder) with the records up to ``last_seq``. ``missing``: the
    seqs this log lacks because of it, the gap between records the note explains (None when it
    lacks none between its records: the file went empty, or before the log's first record)."""

    segment: str
    moved_to: str | None
    last_seq: int
    missing: SeqRange | None = None

    def to_json(self) -> dict[str, Any]:
        missing = self.missing
        return {
            "segment": self.segment,
            "moved_to": self.moved_to,
            "last_seq": self.last_seq,
            "missing": dataclasses.asdict(missing) if missing else None,
        }


@dataclasses.dataclass(frozen=True, slots=True)
class FdrCheck:
    """What a flight-data log holds and whether it is whole. ``gaps``: seqs missing between
    records that no note explains (``noted_gaps``: those ``fdr.records_dropped`` notes name;
    ``moved``: the live segments another program removed or renamed, each with the seqs this
    log lacks because of it: not the recorder's damage, but not in this log either);
    ``went_back``: ``(previous, seq)`` wherever ``seq`` did not grow; ``wall_times``: the
    earliest and the latest record's wall time, ``wall_went_back`` how many times a record's
    wall time is before the one before it (a restart on a computer whose clock was not set: seq
    order is the log's order, never these times); ``unreadable``: lines that
    are not records, as ``segment:line: reason``; ``not_in_log``: records the lock file names,
    waiting on a full disk or lost when the recorder stopped, until a recorder at this path
    writes their note."""

    path: Path
    segments: tuple[Path, ...]
    kinds: Mapping[str, int]
    seqs: SeqRange | None
    wall_times: tuple[str, str] | None
    let_go: int
    noted_gaps: tuple[SeqRange, ...]
    gaps: tuple[SeqRange, ...]
    went_back: tuple[tuple[int, int], ...]
    unreadable: tuple[str, ...]
    not_in_log: DroppedRecords | None
    wall_went_back: int = 0
    moved: tuple[MovedSegment, ...] = ()

    @property
    def records(self) -> int:
        return sum(self.kinds.values())

    @property
    def intact(self) -> bool:
        """No line unreadable, no gap unexplained, ``seq`` always growing."""
        return not (self.gaps or self.went_back or self.unreadable)

    @property
    def moved_away(self) -> tuple[MovedSegment, ...]:
        """The ``moved`` whose records this log lacks (between its records, or before the
        first): another program has them, or removed them."""
        first = self.seqs.first if self.seqs else 0
        return tuple(m for m in self.moved if m.missing or m.last_seq < first)

    def to_json(self) -> dict[str, Any]:
        lost = self.not_in_log
        return {
            "path": str(self.path),
            "intact": self.intact,
            "segments": [str(p) for p in self.segments],
            "records": self.records,
            "kinds": dict(self.kinds),
            "seqs": dataclasses.asdict(self.seqs) if self.seqs else None,
            "wall_times": list(self.wall_times) if self.wall_times else None,
            "wall_went_back": self.wall_went_back,
            "let_go": self.let_go,
            "noted_gaps": [dataclasses.asdict(r) for r in self.noted_gaps],
            "gaps": [dataclasses.asdict(r) for r in self.gaps],
            "went_back": [list(pair) for pair in self.went_back],
            "unreadable": list(self.unreadable),
            "not_in_log": lost.payload() if lost else None,
            "moved": [m.to_json() for m in self.moved],
        }


def log_segments(path: Path) -> tuple[Path, ...]:
    """The segments of the log whose live segment is ``path`` (a name ``live_segment`` has
    resolved): rotated ones by number, then the live one (``InvalidInputError`` when there is
    none, or ``path`` is no regular file)."""
    special = special_kind(path)
    if special is not None:
        raise InvalidInputError(
            "fdr", f"{path} is {special}, not a flight-data log: give the log's live segment"
        )
    found = [p for _, p in rotated_segments(path)] + ([path] if path.is_file() else [])
    if not found:
        raise InvalidInputError("fdr", f"no flight-data log at {path}")
    return tuple(found)


def read_fdr_log(path: Path) -> Iterator[FdrRecord]:
    """Every record of the log at ``path`` (all its segments, oldest first), in file order;
    lines that are not records are skipped here: :func:`check_fdr` names them."""
    for segment in log_segments(live_segment(path)):
        yield from read_fdr(segment)


def check_fdr(path: Path) -> FdrCheck:
    """Read every segment of the log at ``path`` and say what it holds and whether it is
    whole (``InvalidInputError`` when there is no log there, or no line of it is a record).
    ``FdrCheck.path`` is the file ``path`` leads to (``live_segment``), as are its segments."""
    path = live_segment(path)
    segments = log_segments(path)
    kinds: Counter[str] = Counter()
    seqs: list[int] = []
    times: list[str] = []
    notes: list[FdrRecord] = []
    unreadable: list[str] = []
    for segment in segments:
        for record in _records(segment, unreadable):
            kinds[str(record.get("kind"))] += 1
            seqs.append(record["seq"])
            if isinstance(wall := record.get("wall_time"), str):
                times.append(wall)
            if record.get("kind") in (RECORDS_DROPPED, SEGMENT_REPLACED):
                notes.append(record)
    if unreadable and not seqs:
        raise InvalidInputError(
            "fdr",
            f"{path}: no line is a flight-data record (a JSON object with an integer seq): "
            "not a flight-data log, or one damaged throughout",
        )
    gaps, went_back = _follow(seqs)
    dropped = [d for r in notes if r["kind"] == RECORDS_DROPPED and (d := _noted(r.get("payload")))]
    replaced = [
        m for r in notes if r["kind"] == SEGMENT_REPLACED and (m := _moved(r.get("payload")))
    ]
    noted, unexplained, moved = _explain(gaps, tuple(d[0] for d in dropped), replaced)
    instants = _instants(times)
    return FdrCheck(
        path=path,
        segments=segments,
        kinds=dict(sorted(kinds.items())),
        seqs=SeqRange(seqs[0], seqs[-1]) if seqs else None,
        wall_times=_span(times, instants),
        let_go=sum(d[1] for d in dropped),
        noted_gaps=noted,
        gaps=unexplained,
        went_back=tuple(went_back),
        unreadable=tuple(unreadable),
        not_in_log=read_lock(lock_path(path))[1],
        wall_went_back=_went_back(instants),
        moved=moved,
    )


def _explain(
    gaps: list[SeqRange], dropped: tuple[SeqRange, ...], replaced: list[MovedSegment]
) -> tuple[tuple[SeqRange, ...], tuple[SeqRange, ...], tuple[MovedSegment, ...]]:
    """Each gap held against the notes: one the ``dropped`` seqs cover is noted (records let
    go); else one that a ``replaced`` note's ``last_seq`` lies in lacks, up to that seq, the
    records that went with the file moved (its ``missing``; the seqs after it, if any, must be
    covered by ``dropped``); any other gap is unexplained. Returns the noted gaps, the
    unexplained ones and ``replaced`` with their ``missing`` seqs."""
    noted: list[SeqRange] = []
    unexplained: list[SeqRange] = []
    missing: dict[int, SeqRange] = {}
    lasts = sorted({m.last_seq for m in replaced})
    for gap in gaps:
        ends = [last for last in lasts if gap.first <= last <= gap.last]
        went = SeqRange(gap.first, ends[-1]) if ends else None
        if gap.within(dropped):
            noted.append(gap)
        elif went is None or not gap.within((*dropped, went)):
            unexplained.append(gap)
        else:
            missing[went.last] = went
            if gap.last > went.last:
                noted.append(SeqRange(went.last + 1, gap.last))
    found = [dataclasses.replace(m, missing=missing.get(m.last_seq)) for m in replaced]
    return tuple(noted), tuple(unexplained), tuple(found)


def _instants(times: list[str]) -> list[dt.datetime]:
    """The wall times that read as ISO 8601 instants with an offset, in the log's order."""
    read = []
    for text in times:
        with contextlib.suppress(ValueError):
            when = dt.datetime.fromisoformat(text)
            if when.tzinfo is not None:
                read.append(when)
    return read


def _went_back(instants: list[dt.datetime]) -> int:
    """How many times an instant is before the one before it."""
    return sum(later < earlier for earlier, later in itertools.pairwise(instants))


def _span(times: list[str], instants: list[dt.datetime]) -> tuple[str, str] | None:
    """The earliest and the latest of the wall times, in ISO 8601 (``instants``: those that read
    as instants; the first and the last as written, in the log's order, when none does)."""
    if not times:
        return None
    if not instants:
        return times[0], times[-1]
    return min(instants).isoformat(), max(instants).isoformat()


def _records(segment: Path, unreadable: list[str]) -> list[FdrRecord]:
    """The records of ``segment``: its JSON objects with an integer ``seq`` (a bool is none);
    every other line is added to ``unreadable`` as ``segment:line: reason``, in line order."""
    result = read_fdr(segment)
    bad = {n: why for n, _, why in result.corrupt}
    skipped = set(bad)
    numbers = (n for n in itertools.count(1) if n not in skipped)
    records = []
    for number, record in zip(numbers, result, strict=False):
        if type(record.get("seq")) is int:
            records.append(record)
        else:
            bad[number] = "no seq (a JSON object, not a record)"
    unreadable += [f"{segment.name}:{n}: {why}" for n, why in sorted(bad.items())]
    return records


def _noted(payload: Any) -> tuple[SeqRange, int] | None:
    """The seqs a ``fdr.records_dropped`` note names, and how many records it says were lost."""
    if not isinstance(payload, dict):
        return None
    first, last, count = (payload.get(k) for k in ("first_seq", "last_seq", "count"))
    if isinstance(first, int) and isinstance(last, int) and isinstance(count, int):
        return SeqRange(first, last), count
    return None


def _moved(payload: Any) -> MovedSegment | None:
    """The live segment a ``fdr.segment_replaced`` note says went, and where to."""
    if not isinstance(payload, dict):
        return None
    segment, moved_to, last = (payload.get(k) for k in ("segment", "moved_to", "last_seq"))
    if isinstance(segment, str) and isinstance(moved_to, str | None) and type(last) is int:
        return MovedSegment(segment, moved_to, last)
    return None


def _follow(seqs: list[int]) -> tuple[list[SeqRange], list[tuple[int, int]]]:
    """The seqs missing between consecutive records, and each place ``seq`` did not grow."""
    gaps: list[SeqRange] = []
    went_back: list[tuple[int, int]] = []
    for previous, seq in itertools.pairwise(seqs):
        if seq > previous + 1:
            gaps.append(SeqRange(previous + 1, seq - 1))
        elif seq <= previous:
            went_back.append((previous, seq))
    return gaps, went_back
