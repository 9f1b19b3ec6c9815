"""One strategy evaluated on one flight (:class:`StrategyEval`), a strategy that could not be
(:class:`StrategyFailure`) or one stopped part-way (:class:`StrategyStopped`): the rows of
``eval``, and each one's row of the strategy x flight summary (:class:`SummaryRow`). Frozen
values; ``to_json`` gives their ``eval.json`` and ``summary.json`` entries."""

from __future__ import annotations

import errno
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from c3_matcher.errors import describe
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.run.acceptance import Acceptance, Headline
from c3_matcher_tools.run.feature_sources import FDR_LOG, FeatureSources, read_feature_sources
from c3_matcher_tools.run.outputs import (
    flight_report,
    no_report_html,
    write_flight_outputs,
    write_results,
)
from c3_matcher_tools.run.records import FlightRun
from c3_matcher_tools.run.scoring import RunSummary

__all__ = [
    "StrategyEval",
    "StrategyFailure",
    "StrategyRow",
    "StrategyStopped",
    "SummaryRow",
    "WritingStopped",
    "ended_status",
    "strict_json",
    "was_stopped",
    "write_strategy_files",
]


@dataclass(frozen=True)
class StrategyEval:
    """One strategy evaluated on one flight: its first run, its C3-IT measures, the run's
    summary (counts and timing), the map and flight report written for it (``html`` None:
    no matplotlib, or not written) and where its candidates' features came from, as its
    flight-data log says (``features``, read once for its report, ``eval.json`` and the line
    that says a store served none; None: not read). ``stopped``: Ctrl-C or SIGTERM came while
    its files were written, and which were not (None: it finished)."""

    run: FlightRun
    acceptance: Acceptance
    summary: RunSummary
    geojson: str | None
    html: str | None
    features: FeatureSources | None = None
    stopped: str | None = None

    @property
    def strategy(self) -> str:
        return self.run.strategy

    def to_json(self) -> dict[str, Any]:
        """Its ``eval.json`` entry (NaN left for the caller to make strict): the settings it ran
        with, the keypoint budget its backend kept (``keypoint_budget``: the number, where the
        settings may leave it unset for the strategy's own default) and its provenance
        (:attr:`~c3_matcher_tools.run.records.FlightRun.provenance`), and its candidates
        counted by where their features came from (``feature_sources``) when they were read."""
        counted = {} if self.features is None else {"feature_sources": self.features.counts}
        stopped = {} if self.stopped is None else {"stopped": self.stopped}
        return {
            "strategy": self.strategy,
            "settings": self.run.settings,
            "keypoint_budget": self.run.keypoint_budget,
            "lightglue_settings": self.run.lightglue,
            "provenance": self.run.provenance,
            "startup_s": self.run.startup_s,
            "wall_s": self.run.wall_s,
            "timing": self.summary.to_json(),
            "metrics": self.acceptance.to_json(),
            "geojson": self.geojson,
            "html": self.html,
            "per_frame": [
                {
                    "index": o.index,
                    "status": o.status,
                    "true_present": o.true_present,
                    "best_inliers": o.best_inliers,
                    "correct": o.correct,
                    "mean_error_px": _or_none(o.mean_error_px),
                    "telemetry_error_m": _or_none(o.telemetry_error_m),
                    "gnss_accuracy_m": o.gnss_accuracy_m,
                    "gnss_degraded": o.gnss_degraded,
                    "attitude_assumed": o.attitude_assumed,
                    "elapsed_ms": o.elapsed_ms,
                    **({} if o.ambiguous is None else {"ambiguous": o.ambiguous}),
                }
                for o in self.run.outcomes
            ],
            **counted,
            **stopped,
        }


FULL_DISK = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
"""The errors of a write a full disk (or a file-size limit) refused."""


@dataclass(frozen=True)
class StrategyFailure:
    """A strategy that could not be evaluated (it failed to start or to run): a row of the
    table, not the end of the evaluation. ``unwritten``: the file a full disk refused and why,
    where that is what failed it (its run done, its files not all written); else None."""

    strategy: str
    error: str
    unwritten: str | None = None

    @classmethod
    def of(cls, strategy: str, exc: Exception) -> StrategyFailure:
        """The row of ``strategy``, which ``exc`` failed."""
        if isinstance(exc, OSError) and exc.errno in FULL_DISK:
            return cls(strategy, describe(exc), f"{exc.filename}: {exc.strerror}")
        return cls(strategy, describe(exc))

    @staticmethod
    def unwritten_of(rows: Iterable[object]) -> str | None:
        """The first write a full disk refused among ``rows``' failures; None: none."""
        failures = (r for r in rows if isinstance(r, StrategyFailure))
        return next((r.unwritten for r in failures if r.unwritten), None)

    def to_json(self) -> dict[str, Any]:
        unwritten = {} if self.unwritten is None else {"unwritten": self.unwritten}
        return {"strategy": self.strategy, "error": self.error, **unwritten}


@dataclass(frozen=True)
class StrategyStopped:
    """A strategy stopped part-way by Ctrl-C or SIGTERM: of its first run, the frames done and
    those it was to fly, and ``results``, the file that keeps them (None: stopped outside its
    first run's frames; nothing of it kept)."""

    strategy: str
    frames_done: int = 0
    frames_planned: int | None = None
    results: str | None = None

    @property
    def error(self) -> str:
        """What its row says in the tables."""
        if self.results is None:
            return "stopped before its results were written"
        if self.frames_done == self.frames_planned:
            return (
                f"stopped in its second (determinism) run; its first, of {self.frames_done} "
                f"frames, kept (their results: {self.results})"
            )
        return (
            f"stopped after {self.frames_done} of {self.frames_planned} frames "
            f"(their results: {self.results})"
        )

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "stopped": self.error}


StrategyRow = StrategyEval | StrategyFailure | StrategyStopped


class WritingStopped(KeyboardInterrupt):
    """Ctrl-C or SIGTERM came while a strategy's files were written, its figures complete:
    ``row``, those figures and the files not written (:attr:`StrategyEval.stopped`)."""

    def __init__(self, row: StrategyEval) -> None:
        super().__init__(row.stopped)
        self.row = row


def write_strategy_files(
    directory: Path,
    dataset: FlightDataset,
    run: FlightRun,
    acceptance: Acceptance,
    summary: RunSummary,
) -> StrategyEval:
    """A strategy's files in ``directory``, its figures (``acceptance``, ``summary`` of its
    first ``run``) complete: ``results.jsonl``, ``flight.geojson`` and ``report.html``, which
    shows them. Ctrl-C or SIGTERM meanwhile raises :class:`WritingStopped`: the figures kept,
    ``results.jsonl`` written if it was not, the files not written named."""
    case = acceptance.correct_tile.case  # measured: frames given
    try:
        features = read_feature_sources(directory / FDR_LOG)  # once: the log is large
        flight = {
            **flight_report(dataset, run, summary),
            **{f"{k} pass": v.passed for k, v in acceptance.measures().items()},
            "C3-IT-04 case": None if case is None else case.said,
            "feature_sources": features.counts,
        }
        files = write_flight_outputs(directory, dataset, run, flight, say_no_report=False)
    except KeyboardInterrupt as stop:
        raise WritingStopped(_unwritten(directory, run, acceptance, summary)) from stop
    return StrategyEval(run, acceptance, summary, files.geojson, files.html, features)


def _unwritten(
    directory: Path, run: FlightRun, acceptance: Acceptance, summary: RunSummary
) -> StrategyEval:
    """The row of a strategy stopped while its files in ``directory`` were written: its
    figures, ``results.jsonl`` (written now if it was not: each file is replaced atomically,
    so one there is whole) and the map and flight report where they were written."""
    if not (directory / "results.jsonl").is_file():
        write_results(directory / "results.jsonl", run.outcomes)
    geojson, html = directory / "flight.geojson", directory / "report.html"
    expected = [geojson] + ([html] if no_report_html() is None else [])
    missing = [p.name for p in expected if not p.is_file()]
    said = f"stopped while its files were written: {', '.join(missing) or 'none'} not written"
    return StrategyEval(
        run,
        acceptance,
        summary,
        str(geojson) if geojson.is_file() else None,
        str(html) if html.is_file() else None,
        stopped=said,
    )


def was_stopped(row: StrategyRow) -> bool:
    """``row`` is the strategy a Ctrl-C or SIGTERM stopped (part-way, or writing its files)."""
    return isinstance(row, StrategyStopped) or (
        isinstance(row, StrategyEval) and row.stopped is not None
    )


@dataclass(frozen=True)
class SummaryRow:
    """One strategy on one flight in the summary table and ``summary.json``: its headline
    figures, the candidates the matcher was given and those of them dropped for their tiles
    (``tile_dropped``: a damaged tile store, not the matcher), or (``figures`` None) the error
    that stopped it (``stopped``: Ctrl-C or SIGTERM did)."""

    strategy: str
    flight: str
    figures: Headline | None = None
    right_fix_other_tile: int = 0
    frame_ms_p50: float | None = None
    error: str | None = None
    stopped: bool = False
    candidates: int = 0
    tile_dropped: int = 0

    @classmethod
    def of(cls, flight: str, row: StrategyRow) -> SummaryRow:
        """``row``'s summary on ``flight``."""
        if not isinstance(row, StrategyEval):
            stopped = isinstance(row, StrategyStopped)
            return cls(row.strategy, flight, error=row.error, stopped=stopped)
        return cls(
            row.strategy,
            flight,
            row.acceptance.headline,
            len(row.acceptance.false_confident.right_fix_other_tile),
            row.summary.frame_ms_p50,
            error=row.stopped,
            stopped=row.stopped is not None,
            candidates=row.summary.candidates,
            tile_dropped=row.summary.tile_dropped,
        )

    @classmethod
    def not_run(
        cls,
        flights: Sequence[str],
        strategies: Sequence[str],
        said: str = "not run: the evaluation was stopped before this flight",
    ) -> list[SummaryRow]:
        """The rows of the ``flights`` a stop (or a failure, as ``said``) came before: each of
        ``strategies``, not run."""
        return [cls(n, flight, error=said, stopped=True) for flight in flights for n in strategies]

    def to_json(self) -> dict[str, Any]:
        where = {"strategy": self.strategy, "flight": self.flight}
        if self.figures is None:
            return {**where, ("stopped" if self.stopped else "error"): self.error}
        return {
            **where,
            **asdict(self.figures),
            "right_fix_other_tile": self.right_fix_other_tile,
            "frame_ms_p50": self.frame_ms_p50,
            "candidates": self.candidates,
            "tile_dropped": self.tile_dropped,
            **({"stopped": self.error} if self.stopped else {}),
        }


def _or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def strict_json(value: Any) -> Any:
    """``value`` with every NaN or infinity, however deep, made None: what ``eval.json`` and
    ``summary.json`` hold is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    return value


def ended_status(
    summary: Sequence[SummaryRow], refused: Iterable[str | None], say: Callable[[str], None]
) -> int:
    """The exit status of an evaluation that ran to its end, its failures ``say``-d: 0; 1
    where a strategy failed to run on a flight; 2 where a full disk refused a strategy's files
    (``refused``: each flight's refused write, or None), as for every command."""
    failed = [f"{s.strategy} on {s.flight}" for s in summary if s.figures is None]
    if not failed:
        return EXIT_OK
    say(f"failed to run: {', '.join(failed)}")
    full = [why for why in refused if why]
    for why in full:
        say(why)
    return EXIT_USAGE if full else EXIT_FAILURE
