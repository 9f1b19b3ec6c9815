"""A run's ``results.jsonl``: one line a frame (:func:`result_line`), written whole when the run
ends or stops (:func:`write_results`), and meanwhile each frame's line appended, as it is flown,
to ``results.jsonl.partial`` beside it (:func:`appending_results`), flushed to disk, so that a
run killed outright (SIGKILL, out of memory, power cut), which writes no ``results.jsonl``,
still leaves the frames it did, in the lines ``results.jsonl`` would have held for them. The
partial file is removed once ``results.jsonl`` is written."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from c3_matcher.atomic import atomic_writer
from c3_matcher.fdr.files import fsync_dir
from c3_matcher_tools.run.records import FrameOutcome

__all__ = [
    "PARTIAL_SUFFIX",
    "RESULTS_FILE",
    "KeepFrame",
    "appending_results",
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
    and the file left as it is from then on: the run goes on, its results written as it ends.
    The file is closed, not removed, when the block ends (:func:`write_results` removes it)."""
    partial = partial_results(path)
    partial.unlink(missing_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC
    fd = os.open(partial, flags, 0o666)
    try:
        fsync_dir(path.parent)
        yield _appender(fd)
    finally:
        os.close(fd)


def _appender(fd: int) -> KeepFrame:
    """Each outcome's line appended to ``fd`` and synced; after a failed write, nothing more."""
    whole = [0]  # bytes of whole lines written; -1 once a write failed

    def keep(outcome: FrameOutcome) -> None:
        if whole[0] < 0:
            return
        data = result_line(outcome).encode("utf-8", "backslashreplace")  # as atomic_writer
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, whole[0])
            whole[0] = -1
            return
        whole[0] += len(data)

    return keep
