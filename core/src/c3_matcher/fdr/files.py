"""The files beside an FDR segment and the durable ways of writing them: the numbered
rotated segments, the small ``.meta`` state file (replaced atomically), directory fsync and the
cut of a torn last line (kept in ``.torn``).

A rotated segment of the live segment ``<stem><suffix>`` is named ``<stem>.<number><suffix>``,
the number written with at least ``SEGMENT_DIGITS`` digits (``fdr.000001.jsonl``): exactly the
names ``segment_path`` gives are read as segments, so a user's ``fdr.1.jsonl`` beside the log is
not one. A longer number (a millionth rotation) is one only when ``.meta`` has reserved it, as
the recorder does before each rotation: ``fdr.20240105.jsonl``, a copy named by its date, is not
taken for the twenty-millionth segment of a log that never rotated that often."""

from __future__ import annotations

import datetime as dt
import errno
import glob
import itertools
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from c3_matcher import regular_files
from c3_matcher.file_kinds import special_kind
from c3_matcher.json_text import loads_json

SEGMENT_DIGITS = 6
"""The least number of digits of a rotated segment's number (zero-padded)."""
RECORD_KEYS = ("seq", "kind", "recorded_at_ns", "wall_time", "payload")
"""The keys of every record line, in the order the recorder writes them (compact JSON)."""
RECORD_START = f'{{"{RECORD_KEYS[0]}":'.encode()
"""How every record line begins: ``{"seq":``."""
JUDGED_BYTES = 1 << 16
"""How much of a file is read to judge whether it is a log (:func:`is_foreign`)."""
BLOCK_BYTES = 1 << 16
"""How much of a segment is read at a time from its end (:func:`blocks_backward`)."""


def live_segment(path: Path, *, fresh: bool = False) -> Path:
    """The file the log's name ``path`` leads to: ``~`` expanded and every symbolic link
    resolved (``os.path.realpath``), taken once when a log is opened or read. Its lock, rotated
    segments, ``.meta`` and ``.torn`` lie beside this file, so any two names of one file (a link
    to it, a link to a folder above it) are one log with one writer. A link to nothing yet leads
    to the file it names, made with its missing folders as for any path. With ``fresh`` (a log
    started anew, its old files removed: a ground run's) only the folder is resolved: a link at
    the name itself is an old file of the log, removed with the rest and never followed, so a
    link left in an earlier run's folder cannot lead that removal to a file elsewhere."""
    given = Path(path).expanduser()
    if fresh:
        return Path(os.path.realpath(given.parent)) / given.name
    return Path(os.path.realpath(given))


def segment_path(path: Path, number: int) -> Path:
    """The rotated segment ``number`` of the live segment ``path``: ``<stem>.<number><suffix>``."""
    return path.with_name(f"{path.stem}.{number:0{SEGMENT_DIGITS}d}{path.suffix}")


def meta_path(path: Path) -> Path:
    """The ``.meta`` state file of the live segment ``path``: ``<path>.meta``."""
    return path.with_name(path.name + ".meta")


def rotated_segments(path: Path) -> list[tuple[int, Path]]:
    """``(number, path)`` of the rotated segments of the live segment ``path``, by number: the
    files named as ``segment_path`` names them, a number past ``SEGMENT_DIGITS`` digits only up
    to the last one ``.meta`` reserved (see the module docstring)."""
    stem, suffix = path.stem, path.suffix
    reserved = read_meta(meta_path(path)).get("last_segment")
    out = []
    for p in path.parent.glob(f"{glob.escape(stem)}.[0-9]*{glob.escape(suffix)}"):
        digits = p.name[len(stem) + 1 : len(p.name) - len(suffix)]
        if not (digits.isascii() and digits.isdigit()):
            continue
        number = int(digits)  # fdr.1.jsonl, fdr.0000001.jsonl: not names the recorder gives
        if p.name == segment_path(path, number).name and (
            len(digits) == SEGMENT_DIGITS or (type(reserved) is int and number <= reserved)
        ):
            out.append((number, p))
    return sorted(out)


def refusal(path: Path, *, fresh: bool = False) -> str | None:
    """Why the recorder may not write its live segment at ``path`` (None: it may): a directory;
    something that is not a regular file (a device, a FIFO, a socket: judged by ``stat``, never
    opened, so never read or waited on); a file where a folder above it should be; a file
    holding something other than records (:func:`is_foreign`). With ``fresh`` a link at
    ``path`` is not judged by what it leads to: it is removed, never followed
    (:func:`live_segment`)."""
    if fresh and path.is_symlink():
        return None
    special = special_kind(path)
    if special == "a directory":
        return "is a directory (give a file path)"
    if special is not None:
        return f"is {special}, not a regular file: give a file path"
    in_the_way = file_in_the_way(path.parent)
    if in_the_way is not None:
        return f"{in_the_way} is not a directory"
    if is_foreign(path):
        return "holds something other than flight-data records: give another path"
    return None


def is_foreign(path: Path) -> bool:
    """Whether ``path`` holds something other than a log of records, judged by its first line
    (:func:`begins_a_log`, the first ``JUDGED_BYTES`` read). A file of NUL bytes alone is a log
    (a power cut during the first line, on a file system that had committed the new size but
    not the data: a torn tail, cut on open); one that only begins with them is not (a video).
    An empty file is a log; a file that cannot be read is not judged here (opening it reports
    that)."""
    try:
        with path.open("rb") as fh:
            head = fh.read(JUDGED_BYTES)
            if head.startswith(b"\0"):
                rest = iter(lambda: fh.read(JUDGED_BYTES), b"")  # block by block
                return any(block.strip(b"\0") for block in itertools.chain([head], rest))
            return bool(head) and not begins_a_log(head, whole=not fh.read(1))
    except OSError:
        return False


def begins_a_log(head: bytes, *, whole: bool) -> bool:
    """Whether ``head``, the first bytes of a file (all of them when ``whole``), begin a log of
    records: a first line that is a record (:func:`is_record_line`); a first line longer than
    ``head`` that begins as a record line does (``RECORD_START``); or, in a file with no
    newline, a first record cut by a power cut: a start of a record line, whole or cut short,
    NUL bytes after it where the file system had not committed the data. A JSON document
    (pretty-printed: a lone ``{``; an object that is not a record) is not a log."""
    end = head.find(b"\n")
    if end >= 0:
        return is_record_line(head[:end])
    if not whole:
        return head.startswith(RECORD_START)
    cut = head.rstrip(b"\0")
    if not (cut.startswith(RECORD_START) or RECORD_START.startswith(cut)):
        return False
    try:
        loads_json(cut)
    except ValueError:
        return True  # cut short
    return is_record_line(cut)  # whole but for its newline: a record, or a one-line document


def is_record_line(line: bytes) -> bool:
    """Whether ``line`` is a JSON object with every key of a record (``RECORD_KEYS``)."""
    value = json_object(line)
    return value is not None and all(key in value for key in RECORD_KEYS)


def json_object(line: bytes) -> dict[str, Any] | None:
    """The JSON object ``line`` holds; None when it holds no JSON, or JSON that is no object."""
    try:
        value = loads_json(line)
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def read_meta(path: Path) -> dict[str, Any]:
    """The ``.meta`` state (last segment number, last seq); {} when absent, unreadable or no
    regular file (a FIFO there is not opened: it would be waited on)."""
    if special_kind(path) is not None:
        return {}
    try:
        data = loads_json(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def write_meta(path: Path, data: Mapping[str, Any]) -> None:
    """Atomically replace the small state file (never a segment)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)  # a file left by a stop, or a link: made anew, never followed
    try:
        with os.fdopen(open_regular(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL), "wb") as fh:
            fh.write(json.dumps(dict(data)).encode())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)  # give back what a full disk let us take
        raise


def fsync_dir(directory: Path) -> None:
    """Make a rename, unlink or new file in ``directory`` durable."""
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def file_in_the_way(directory: Path) -> Path | None:
    """The nearest of ``directory`` and the folders above it that exists, when that is not a
    directory (a file where a folder is wanted); None otherwise."""
    for place in (directory, *directory.parents):
        if place.exists():
            return None if place.is_dir() else place
    return None


def make_dirs_durably(directory: Path) -> None:
    """``mkdir -p`` whose new directories survive a power cut (each one's parent fsynced); a
    file where a folder should be is ``NotADirectoryError`` "<file> is not a directory"."""
    in_the_way = file_in_the_way(directory)
    if in_the_way is not None:
        refused = NotADirectoryError(f"{in_the_way} is not a directory")
        refused.errno = errno.ENOTDIR
        raise refused
    missing = [d for d in (directory, *directory.parents) if not d.exists()]
    directory.mkdir(parents=True, exist_ok=True)
    for made in reversed(missing):
        fsync_dir(made.parent)


def remove_log(path: Path, torn_path: Path) -> None:
    """Remove every file of the log whose live segment is ``path`` (its rotated segments,
    ``.meta``, the ``torn_path`` beside it) but the lock, durably."""
    previous = [path, *(p for _, p in rotated_segments(path)), meta_path(path), torn_path]
    for p in previous:
        p.unlink(missing_ok=True)
    fsync_dir(path.parent)


def drop_half_rotated_live(path: Path) -> None:
    """Should the live segment ``path`` and the newest rotated one be one file under two names
    (a rotation by hard link interrupted), drop the live name: the rotated one keeps the data."""
    if not path.exists():
        return
    live = path.stat()
    for _, p in rotated_segments(path)[-1:]:
        st = p.lstat()  # a symbolic link to the live segment is no half rotation
        if (st.st_dev, st.st_ino) == (live.st_dev, live.st_ino):
            path.unlink()
            fsync_dir(path.parent)


def open_for_append(path: Path) -> int:
    """``path`` opened to append; a file this creates is made durable in its directory, so
    that the records fsynced into it survive a power cut with it."""
    created = not os.path.lexists(path)
    fd = open_regular(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    if created:
        try:
            fsync_dir(path.parent)
        except OSError:
            os.close(fd)
            raise
    return fd


class NotRegularFileError(OSError):
    """A file of the log the recorder would write (its lock, ``.meta``, ``.torn``, the live
    segment) that is a symbolic link at its name or no regular file: refused, never written
    through, so a link left beside a log cannot lead a write (or a cut) to a file elsewhere."""


def open_regular(path: Path, flags: int) -> int:
    """``path`` opened by ``os.open`` with ``flags`` (made 0o644 when ``O_CREAT`` creates it),
    never through a symbolic link at its name (``O_NOFOLLOW``) and only when it is a regular
    file (a FIFO is not waited on): else :class:`NotRegularFileError` naming it."""
    try:
        return regular_files.open_regular(path, flags | os.O_NOFOLLOW)
    except regular_files.SpecialFileError as exc:
        raise NotRegularFileError(errno.EINVAL, _not_regular(path, exc.kind)) from exc
    except OSError as exc:
        kind = "a symbolic link" if path.is_symlink() else special_kind(path)
        if kind is None:
            raise
        raise NotRegularFileError(exc.errno, _not_regular(path, kind)) from exc


def _not_regular(path: Path, kind: str) -> str:
    """Why the recorder writes no file of its log at ``path``, which is ``kind``."""
    return (
        f"{path} is {kind}, not a regular file: the recorder writes no file of its log through "
        "a link or into anything else; remove it, or give another path"
    )


@dataclass(frozen=True, slots=True)
class TornCut:
    """A torn tail cut from a segment: where, how many bytes, and why they could not be kept
    aside ("" when they were)."""

    offset: int
    length: int
    not_kept: str = ""


def cut_torn_tail(path: Path, torn_path: Path, end: int | None = None) -> TornCut | None:
    """Cut the segment ``path`` back to its last complete line, or to ``end`` when it is
    shorter (where a record began whose write failed and could not be rolled back: its line may
    be whole, but it was never acknowledged and will be written again); append the cut bytes to
    ``torn_path`` (one JSON line per cut: segment, offset, length, wall time, the bytes). The
    cut is made even when they cannot be kept (a full disk): they are part of a record never
    acknowledged, and appending after them would spoil the next. None when nothing was cut."""
    if not path.exists():
        return None
    with os.fdopen(open_regular(path, os.O_RDWR), "r+b") as fh:
        size = os.fstat(fh.fileno()).st_size
        keep = end if end is not None and end < size else _complete_lines(fh, size)
        if keep == size:
            return None
        fh.seek(keep)
        cut = fh.read()
        side = {
            "segment": path.name,
            "offset": keep,
            "length": len(cut),
            "cut_at_wall_time": dt.datetime.now(dt.UTC).isoformat(timespec="microseconds"),
            "bytes": cut.decode("utf-8", "backslashreplace"),
        }
        not_kept = _keep_aside(torn_path, (json.dumps(side) + "\n").encode())
        fh.truncate(keep)
        fh.flush()
        os.fsync(fh.fileno())
    return TornCut(keep, len(cut), not_kept)


def _complete_lines(fh: BinaryIO, size: int) -> int:
    """How many of the ``size`` bytes of ``fh`` end with its last newline (``size`` when the
    last byte is one, or the file is empty)."""
    for offset, block in blocks_backward(fh, size):
        end = block.rfind(b"\n")
        if end >= 0:
            return offset + end + 1
    return 0


def blocks_backward(
    fh: BinaryIO, size: int, block: int = BLOCK_BYTES
) -> Iterator[tuple[int, bytes]]:
    """The first ``size`` bytes of ``fh`` from the end back, ``block`` bytes at a time (the
    first block of the file may be shorter), each with its offset in the file."""
    pos = size
    while pos > 0:
        start = max(0, pos - block)
        fh.seek(start)
        yield start, fh.read(pos - start)
        pos = start


def _keep_aside(torn_path: Path, line: bytes) -> str:
    """Append ``line`` to ``torn_path`` durably; "" when done, else why not."""
    try:
        side_fd = open_for_append(torn_path)
        try:
            if os.write(side_fd, line) != len(line):
                raise OSError(errno.EIO, "short write")
            os.fsync(side_fd)
        finally:
            os.close(side_fd)
    except OSError as exc:
        return f"{torn_path}: {exc.strerror or exc}"
    return ""
