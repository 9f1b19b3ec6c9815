"""What a recorder restarting on an existing log reads of it: the seqs at the log's end, read
from the end back a block at a time, only as far as the restart needs them.

The recorder gives each record the next seq and writes records in that order, so along the log
``seq`` rises record by record: the last record's is the largest, and the records the lock file
names as lost (waiting when the last recorder stopped, some of which may have reached the log)
can only follow every record whose seq is below the first one it names. A read from the end
checks that rise in all it reads, a block of lines at least; where it fails (a damaged log: a
seq repeated or going back, a record whose seq is not a whole number from 1), the segments are
read whole, line by line, as a restart always read them before. What the read from the end
cannot see is a seq going back further from the end than it reads (a log damaged by something
other than the recorder): ``c3-matcher fdr`` reports that damage, and the restart goes on after
the last record."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import BinaryIO

from c3_matcher.fdr.files import BLOCK_BYTES, blocks_backward, json_object, rotated_segments


def recent_seqs(path: Path, back_to: int | None = None) -> list[int]:
    """The seqs a restart needs of the newest rotated segment and the live one, ``path``: the
    largest, and every one from ``back_to`` (the first seq the lock file names as lost) on.
    Read from the end (:func:`tail_seqs`); when the end read does not rise record by record,
    every seq of both segments (:func:`all_seqs`)."""
    segments = [p for p in [*(q for _, q in rotated_segments(path)[-1:]), path] if p.exists()]
    tail = tail_seqs(segments, back_to)
    return all_seqs(segments) if tail is None else tail


def tail_seqs(
    segments: Sequence[Path], back_to: int | None, block: int = BLOCK_BYTES
) -> list[int] | None:
    """The seqs of the last records of ``segments`` (oldest first), last first, read from the
    end back: at least ``block`` bytes of lines, then up to the first record whose seq is below
    ``back_to`` (None: the first record). None when a record read does not rise above the one
    before it (its seq repeated, going back, or no whole number from 1): a damaged log, whose
    largest seq may lie anywhere."""
    seqs: list[int] = []
    checked = 0  # bytes of the lines read
    for segment in reversed(segments):
        with segment.open("rb") as fh:
            for line in lines_backward(fh, block):
                checked += len(line)
                seq = line_seq(line)
                if seq is None:
                    continue  # a damaged line: a full read counts nothing for it either
                if type(seq) is not int or seq < 1 or (seqs and seq >= seqs[-1]):
                    return None
                seqs.append(seq)
                if checked >= block and (back_to is None or seq < back_to):
                    return seqs
    return seqs


def all_seqs(segments: Sequence[Path]) -> list[int]:
    """Every seq of ``segments`` in order, each line parsed in turn (none kept but its seq)."""
    seqs: list[int] = []
    for segment in segments:
        with segment.open("rb") as fh:
            for line in fh:
                seq = line_seq(line) if line.endswith(b"\n") else None  # not a torn line
                if seq is not None:
                    seqs.append(seq)
    return seqs


def line_seq(line: bytes) -> int | None:
    """The seq a record line counts for: a JSON object's ``seq`` when it is an int (0 when it
    has none, as a restart always counted it); None for a line that is no JSON object, or whose
    ``seq`` is something else (a damaged line)."""
    record = json_object(line)
    if record is None:
        return None
    seq = record.get("seq", 0)
    return seq if isinstance(seq, int) else None


def lines_backward(fh: BinaryIO, block: int = BLOCK_BYTES) -> Iterator[bytes]:
    """The complete lines of ``fh`` (each with its newline) from the last back to the first,
    read ``block`` bytes at a time; bytes after the last newline (a torn line) are none. What
    it holds at once: a block and the line being read."""
    ends: list[bytes] = []  # the end of a line whose start is not read yet, the last part first
    torn = True  # no newline found yet: the bytes read are after the last one
    for _, data in blocks_backward(fh, fh.seek(0, 2), block):
        if torn:
            last = data.rfind(b"\n")
            if last < 0:
                continue
            data, torn = data[: last + 1], False
        first = data.find(b"\n")
        if first < 0:
            ends.append(data)
            continue
        whole = data[first + 1 :] + b"".join(reversed(ends))
        ends = [data[: first + 1]]
        yield from (line + b"\n" for line in reversed(whole.split(b"\n")[:-1]))
    if ends:
        yield b"".join(reversed(ends))  # the file's first line
