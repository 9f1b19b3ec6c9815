"""A run's mark (:data:`RUN_MARK`): the file ``replay`` and ``eval`` write first into each
output directory they take, saying whose output it is (:class:`RunLayout`: what each command
writes there, and how an earlier run of it is known) and whether the run is in progress,
ended, failed or stopped part-way; and how a run's small JSON files are read back
(:func:`run_json_file`)."""

from __future__ import annotations

import json
from collections.abc import Callable
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
    "mark_ended",
    "mark_failed",
    "mark_stopped",
    "marked_by",
    "run_json_file",
    "run_mark",
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


def mark_ended(directory: Path, failed: str | None = None) -> None:
    """``directory``'s :data:`RUN_MARK` rewritten without ``running``: the run ended, its
    files written; or, with ``failed`` (why, as ``"failed"``), ended with some not written."""
    mark = run_json_file(directory / RUN_MARK)
    if isinstance(mark, dict) and "running" in mark:
        ended = {k: v for k, v in mark.items() if k != "running"}
        ended |= {} if failed is None else {"failed": failed}
        write_text_atomically(directory / RUN_MARK, json.dumps(ended) + "\n")


def mark_failed(directory: Path, refused: OSError, say: Callable[[str], None]) -> None:
    """``directory``'s run marked ended, failed: ``refused``, the write a full disk refused,
    named as the ``"failed"`` of its :data:`RUN_MARK`. A disk too full even for that leaves it
    saying ``running`` (what a killed run leaves), and ``say``-s so rather than leave it to be
    read as a kill."""
    try:
        why = f"{refused.filename or directory}: {refused.strerror or refused}"
        mark_ended(directory, failed=why)
    except OSError as unmarked:
        say(f"{directory / RUN_MARK} still says running: {unmarked}")


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
