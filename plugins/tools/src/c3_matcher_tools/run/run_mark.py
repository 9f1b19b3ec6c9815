"""A run's mark (:data:`RUN_MARK`): the file ``replay`` and ``eval`` write first into each
output directory they take, saying whose output it is (:class:`RunLayout`: what each command
writes there, and how an earlier run of it is known) and whether the run is in progress,
ended, failed or stopped part-way; and how a run's small JSON files are read back
(:func:`run_json_file`)."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher.json_text import loads_json

if TYPE_CHECKING:
    from c3_matcher_tools.dataset.format import FlightDataset
    from c3_matcher_tools.run.records import FlightRun

__all__ = [
    "RUN_MARK",
    "RunLayout",
    "mark_each_ended",
    "mark_ended",
    "mark_stopped",
    "marked_by",
    "refused_write",
    "run_json_file",
    "run_mark",
    "say_ended",
]

RUN_MARK = "run.json"
"""The file ``replay`` and ``eval`` write first into each output directory they take, naming
the command (``{"command": "c3-matcher replay"}``), the dataset's resolved path and replay's
strategy, and ``"running": true`` until the run ends (:func:`mark_ended`; ``"failed"`` where
its files could not all be written): the directory is that command's output, which a later
run of it replaces (``outputs.check_output_dirs``)."""
_LARGEST_REPORT = 1 << 26
"""The most bytes read of a file to tell whether it is a run's mark or report (theirs are far
smaller)."""


@dataclass(frozen=True)
class RunLayout:
    """What ``c3-matcher <command>`` writes in an output directory, and how an earlier run of it
    is known there: by its :data:`RUN_MARK`, or, in a directory without one (a run written
    before runs were marked), by ``report``, a JSON object holding ``keys``. ``summary``: the
    report of a run over several flights, written beside a directory per flight (None: the
    command has no such run)."""

    command: str
    report: str
    keys: frozenset[str]
    summary: str | None = None

    @property
    def mark(self) -> dict[str, str]:
        """What its :data:`RUN_MARK` holds."""
        return {"command": f"c3-matcher {self.command}"}

    def holds_run(self, directory: Path) -> bool:
        """``directory`` holds an earlier run of the command: its mark, or, with no
        :data:`RUN_MARK` at all, its report."""
        if (directory / RUN_MARK).is_symlink() or (directory / RUN_MARK).exists():
            return marked_by(directory) == self.mark["command"]
        report = run_json_file(directory / self.report)
        return isinstance(report, dict) and self.keys <= report.keys()


def run_mark(
    layout: RunLayout, dataset: FlightDataset | None, strategy: str | None = None
) -> dict[str, Any]:
    """What a run of ``layout`` over ``dataset`` with ``strategy`` marks its output directory
    with (:data:`RUN_MARK`): the command, the dataset's resolved path and name, the strategy."""
    where = (
        {}
        if dataset is None
        else {"dataset": str(dataset.root.expanduser().resolve()), "name": dataset.name}
    )
    return {**layout.mark, **where, **({} if strategy is None else {"strategy": strategy})}


def mark_ended(directory: Path, failed: str | None = None, *, complete: bool = True) -> None:
    """``directory``'s :data:`RUN_MARK` rewritten without ``running``: the run ended, its
    files written; or, with ``failed`` (why, as ``"failed"``), ended with some not written;
    ``complete`` False, stopped before all of it ran there (``"complete": false``)."""
    mark = run_json_file(directory / RUN_MARK)
    if isinstance(mark, dict) and "running" in mark:
        ended = {k: v for k, v in mark.items() if k != "running"}
        ended |= {} if failed is None else {"failed": failed}
        ended |= {} if complete else {"complete": False}
        write_text_atomically(directory / RUN_MARK, json.dumps(ended) + "\n")


def refused_write(refused: OSError, directory: Path) -> str:
    """What a run's ``"failed"`` says of ``refused``, a write a full disk refused: its file
    (else ``directory``) and why."""
    return f"{refused.filename or directory}: {refused.strerror or refused}"


def say_ended(
    directory: Path, say: Callable[[str], None], failed: str | None = None, complete: bool = True
) -> bool:
    """:func:`mark_ended`; False where a disk too full even for that leaves the mark saying
    ``running`` (what a killed run leaves), ``say``-ing so rather than leave it to be read as a
    kill."""
    try:
        mark_ended(directory, failed, complete=complete)
    except OSError as unmarked:
        say(f"{directory / RUN_MARK} still says running: {unmarked}")
        return False
    return True


def mark_each_ended(
    directories: Sequence[Path],
    layout: RunLayout,
    say: Callable[[str], None],
    refused: Mapping[Path, str | None],
    failure: OSError | None = None,
) -> list[Path]:
    """Each of a run's ``directories`` (one a flight) marked ended (:func:`say_ended`, each
    apart): complete where its own ``layout.report`` was written and says so, not where the
    run stopped in it or before it; failed where ``refused`` names a write a full disk refused
    there, or where the ``failure`` that ended the run was a write of a file in it. Those whose
    mark could not be written, returned."""
    unmarked: list[Path] = []
    for directory in directories:
        report = run_json_file(directory / layout.report)
        complete = isinstance(report, dict) and report.get("complete") is True
        failed = refused.get(directory)
        if failure is not None and _lies_in(failure.filename, directory):
            failed = refused_write(failure, directory)
        if not say_ended(directory, say, failed, complete):
            unmarked.append(directory)
    return unmarked


def _lies_in(filename: object, directory: Path) -> bool:
    """Whether the file ``filename`` (an OSError's, None for none) lies below ``directory``."""
    if not isinstance(filename, str | bytes):
        return False
    return Path(directory).absolute() in Path(os.fsdecode(filename)).absolute().parents


def mark_stopped(layout: RunLayout, directory: Path, run: FlightRun) -> Path:
    """Mark ``directory`` as holding ``run``, stopped part-way: its :data:`RUN_MARK` says so
    (``"complete": false``, the frames done and those it was to fly), written before the
    run's results, so that no reader takes them for a whole run's."""
    mark = run_json_file(directory / RUN_MARK)
    kept = {k: v for k, v in mark.items() if k != "running"} if isinstance(mark, dict) else {}
    return write_text_atomically(
        directory / RUN_MARK, json.dumps({**layout.mark, **kept, **run.progress}) + "\n"
    )


def run_json_file(path: Path) -> Any:
    """What the JSON file ``path`` of a run holds (its mark, report or summary); None when it is
    no regular file, is larger than a run's mark or report can be, or cannot be read or parsed."""
    try:
        if not path.is_file() or path.stat().st_size > _LARGEST_REPORT:
            return None
        return loads_json(path.read_bytes())
    except (OSError, ValueError):
        return None


def marked_by(directory: Path) -> str | None:
    """The command ``directory``'s :data:`RUN_MARK` names; None without one that names one."""
    mark = run_json_file(directory / RUN_MARK)
    command = mark.get("command") if isinstance(mark, dict) else None
    return command if isinstance(command, str) else None
