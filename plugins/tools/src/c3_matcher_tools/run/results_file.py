"""A run's ``results.jsonl``: one line a frame (:func:`result_line`), written whole when the run
ends or stops (:func:`write_results`), and meanwhile each frame's line appended, as it is flown,
to ``results.jsonl.partial`` beside it (:func:`appending_results`), flushed to disk, so that a
run killed outright (SIGKILL, out of memory, power cut), which writes no ``results.jsonl``,
still leaves the frames it did, in the lines ``results.jsonl`` would have held for them. The
partial file is removed once ``results.jsonl`` is written; one that stops taking frames (a full
disk) says so once on stderr, naming the frames it keeps (:func:`kept_frames` counts them)."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from c3_matcher.atomic import atomic_writer
from c3_matcher.fdr.files import fsync_dir
from c3_matcher.terminal_text import without_controls
from c3_matcher_tools.run.records import FrameOutcome

__all__ = [
    "PARTIAL_SUFFIX",
    "RESULTS_FILE",
    "KeepFrame",
    "appending_results",
    "kept_frames",
    "partial_results",
    "result_line",
    "write_results",
]

RESULTS_FILE = "results.jsonl"
"""A run's results in its output directory (replay's, and each strategy's of eval)."""
PARTIAL_SUFFIX = ".partial"
"""What the file of the frames flown so far adds to the name of the results it stands for."""

KeepFrame = Callable[[FrameOutcome], None]
"""What is called with each frame's outcome as it is flown (:func:`appending_results`)."""


def partial_results(path: Path) -> Path:
    """The file beside the results ``path`` that holds the lines of the frames flown so far
    (``results.jsonl.partial``)."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


def result_line(outcome: FrameOutcome) -> str:
    """``outcome``'s line of ``results.jsonl`` (its ``to_json()``, newline-ended): the one
    format of both the results and the partial file."""
    return json.dumps(outcome.to_json()) + "\n"


def write_results(path: Path, outcomes: Sequence[FrameOutcome]) -> Path:
    """``path`` (JSON Lines): each outcome's line, in order, replaced whole; then the partial
    file beside it (:func:`partial_results`) removed: the results now hold its frames."""
    with atomic_writer(path) as fh:
        for o in outcomes:
            fh.write(result_line(o))
    partial = partial_results(path)
    if partial.is_symlink() or partial.is_file():
        partial.unlink(missing_ok=True)
        fsync_dir(path.parent)
    return path


@contextlib.contextmanager
def appending_results(path: Path) -> Iterator[KeepFrame]:
    """A :data:`KeepFrame` that appends each outcome's line to the partial file of the results
    ``path`` (:func:`partial_results`, started afresh: an earlier one, or a link there, is
    removed, never followed) and flushes it to disk (``fsync``: a few milliseconds, beside a
    frame's hundreds). A write that fails (a full disk) is cut back to the last whole line
    and the file left as it is from then on, said once on stderr, with why and how many frames
    it keeps: the run goes on, its results written as it ends. The file is closed, not
    removed, when the block ends (:func:`write_results` removes it)."""
    partial = partial_results(path)
    partial.unlink(missing_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC
    fd = os.open(partial, flags, 0o666)
    try:
        fsync_dir(path.parent)
        yield _appender(fd, _stopped_line(path))
    finally:
        os.close(fd)


def kept_frames(path: Path) -> int | None:
    """How many frames the partial file of the results ``path`` keeps (its whole lines); None
    when there is none, or it cannot be read."""
    partial, lines = partial_results(path), 0
    try:
        with partial.open("rb") as fh:
            while chunk := fh.read(1 << 20):
                lines += chunk.count(b"\n")
    except OSError:
        return None
    return lines


def _appender(fd: int, stopped: Callable[[int, OSError], str]) -> KeepFrame:
    """Each outcome's line appended to ``fd`` and synced; after a failed write, nothing more,
    and the line ``stopped`` makes of the frames kept and the error said once on stderr."""
    whole, lines = 0, 0  # bytes and lines written whole
    failed = False

    def keep(outcome: FrameOutcome) -> None:
        nonlocal whole, lines, failed
        if failed:
            return
        data = result_line(outcome).encode("utf-8", "backslashreplace")  # as atomic_writer
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, whole)
            failed = True
            _say_on_stderr(stopped(lines, exc))
            return
        whole, lines = whole + len(data), lines + 1

    return keep


def _stopped_line(path: Path) -> Callable[[int, OSError], str]:
    """The line that says the partial file of the results ``path`` stopped taking frames: the
    error, the frames it keeps, and that the run goes on to write ``path`` as it ends."""

    def line(kept: int, exc: OSError) -> str:
        return (
            f"c3-matcher: {partial_results(path)}: {exc.strerror or exc}: it keeps the first "
            f"{kept} frame(s) and takes no more; the run goes on, and writes every frame's "
            f"result to {path.name} as it ends"
        )

    return line


def _say_on_stderr(line: str) -> None:
    """``line`` on stderr, on a line of its own (a progress bar drawn in place is ended first);
    lost, not the run, when stderr cannot be written."""
    with contextlib.suppress(OSError, ValueError):
        newline = "\n" if sys.stderr.isatty() else ""
        print(newline + without_controls(line), file=sys.stderr, flush=True)
