"""What an earlier ``eval`` left in its output directory for a flight, removed before a new one
runs there (:func:`forget_earlier_strategies`): a run stopped part-way, or one of fewer
strategies, leaves no earlier run's results under its mark."""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Collection, Sequence
from pathlib import Path

from c3_matcher.fdr.files import remove_log
from c3_matcher.fdr.pending import lock_path
from c3_matcher_tools.dataset.format import name_problem
from c3_matcher_tools.run.evaluation import StrategyRow, StrategyStopped
from c3_matcher_tools.run.feature_sources import FDR_LOG
from c3_matcher_tools.run.outputs import (
    EVAL_RUN,
    REPLAY_RUN,
    RUN_FILES,
    forget_previous_run,
)
from c3_matcher_tools.run.results_file import RESULTS_FILE, partial_results
from c3_matcher_tools.run.run_mark import run_json_file

__all__ = ["forget_earlier_strategies", "forget_not_reached", "forget_strategies"]

_STRATEGY_FILES = (
    *(f for f in RUN_FILES if f != REPLAY_RUN.report),
    "matcher.log",
    partial_results(Path(RESULTS_FILE)).name,  # the frames a killed run flew
)
"""What eval's run of a strategy writes in its directory (and its second run's) beside the FDR."""


def forget_earlier_strategies(out: Path, kept: Collection[str], *, log: str) -> None:
    """:func:`forget_strategies` of every strategy the earlier eval's report in ``out`` names
    (ran, failed, stopped or not run) but ``kept``, those this run plans (each replaces its own
    as its run starts; one that cannot start leaves its directory as it was): a rerun of fewer
    strategies leaves no earlier one's results under its mark."""
    named = _named_strategies(out / EVAL_RUN.report)
    forget_strategies(out, [n for n in named if n not in kept], log=log)


def forget_strategies(out: Path, names: Sequence[str], *, log: str) -> None:
    """The directory of each strategy of ``names`` in ``out`` emptied of what eval's runs write
    there (:data:`_STRATEGY_FILES`, the FDR ``log``; its second run's, ``run2``, too) and
    removed when that empties it (a stopped run's, for the strategies it never reached). A file
    no run writes stays, as does a link, and a run whose FDR another process writes (its lock
    held); a name that is not one plain path component is passed over."""
    for name in names:
        if name_problem(name) is None:  # one plain path component below ``out``
            _forget_run_dir(out / name / "run2", log)  # inside it, first
            _forget_run_dir(out / name, log)


def _named_strategies(report_path: Path) -> list[str]:
    """The strategies the eval report at ``report_path`` names, in order, once each; none when
    it is missing, no JSON object or too large for one."""
    report = run_json_file(report_path)
    lists = (report.get("strategies"), report.get("not_run")) if isinstance(report, dict) else ()
    named = [
        e.get("strategy") if isinstance(e, dict) else e
        for s in lists
        if isinstance(s, list)
        for e in s
    ]
    return list(dict.fromkeys(n for n in named if isinstance(n, str)))


def _forget_run_dir(directory: Path, log: str) -> None:
    """What a run wrote in ``directory`` removed, its FDR's lock held (as a recorder holds it to
    remove an earlier log), then the directory if that empties it."""
    if directory.is_symlink() or not directory.is_dir():
        return
    lock = lock_path(directory / log)
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError:  # a link, or not writable: left as it is
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # another process writes the FDR
        os.close(fd)
        return
    try:
        remove_log(directory / log, directory / f"{log}.torn")
        forget_previous_run(directory, (*_STRATEGY_FILES, lock.name))
        with contextlib.suppress(OSError):  # not empty: a file no run writes is left
            directory.rmdir()
    finally:
        os.close(fd)


def forget_not_reached(
    out: Path,
    rows: Sequence[StrategyRow],
    not_run: Sequence[str],
    later: Sequence[Path],
    names: Sequence[str],
) -> None:
    """A stopped run's strategies it never reached (not run, or stopped before any result of
    theirs was kept), in ``out`` and in the ``later`` flights' directories: their earlier runs'
    files removed (each would have replaced its own as it started), so none stands under this
    run's mark; one that could not start keeps its own."""
    unkept = [r.strategy for r in rows if isinstance(r, StrategyStopped) and r.results is None]
    forget_strategies(out, [*unkept, *not_run], log=FDR_LOG)
    for directory in later:
        forget_strategies(directory, names, log=FDR_LOG)
