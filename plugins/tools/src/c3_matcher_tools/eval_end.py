"""How ``c3-matcher eval`` ends: what it did so far (:class:`EvalRun`), each flight's directory
marked as it was left (complete where its report was written whole; failed where its own file
was a write a full disk refused), those never reached emptied of an earlier run's strategies,
what it did said on stdout (one JSON document, or the summary table) unless stdout is what
failed, and its exit status: 130 or 143 where Ctrl-C or SIGTERM stopped it (in a strategy's
frames or as the files were written), with the line that says where; 2 where a full disk
refused a write, a flight's ``run.json`` included."""

from __future__ import annotations

import json
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from c3_matcher.commands import EXIT_USAGE
from c3_matcher.context import CommandContext
from c3_matcher_tools.eval_tables import print_summary_table
from c3_matcher_tools.run.evaluation import SummaryRow, ended_status, strict_json
from c3_matcher_tools.run.feature_sources import FDR_LOG
from c3_matcher_tools.run.forget import forget_strategies
from c3_matcher_tools.run.outputs import EVAL_RUN
from c3_matcher_tools.run.run_mark import RUN_MARK, mark_each_ended

__all__ = ["EvalRun"]


@dataclass
class EvalRun:
    """What an evaluation of the ``flights`` (their names, each into its directory of ``outs``)
    with the ``strategies`` has done so far: the summary's rows (those a stop came before, not
    run), each flight's report, by directory the write a full disk refused (None: none), the
    directories it started, and the signal that stopped it outside a strategy's frames (None:
    none did). ``several``: its JSON document holds each flight's report and the summary."""

    flights: Sequence[str]
    outs: Sequence[Path]
    strategies: Sequence[str]
    several: bool
    summary: list[SummaryRow] = field(default_factory=list)
    reports: list[dict[str, Any]] = field(default_factory=list)
    refused: dict[Path, str | None] = field(default_factory=dict)
    started: list[Path] = field(default_factory=list)
    stopped_by: int | None = None

    @staticmethod
    def say(ctx: CommandContext) -> Callable[[str], None]:
        """Say a line of the evaluation's on stderr."""
        return lambda line: ctx.err(f"c3-matcher eval: {line}")

    def summary_rows(self) -> list[Any]:
        """The summary's rows as ``summary.json`` holds them."""
        rows: list[Any] = strict_json([s.to_json() for s in self.summary])
        return rows

    def show(self, ctx: CommandContext, *, as_json: bool) -> None:
        """What it did, on stdout: one JSON document (the one flight's ``eval.json``, or for
        several ``{"flights": [each one's eval.json, in order], "summary": summary.json's
        rows}``), else the summary table; of one flight, nothing before its report was
        written."""
        if not as_json:
            if self.summary:
                print_summary_table(ctx, self.summary)
        elif self.several:  # even when a stop or a failure came before the second
            document = {"flights": list(self.reports), "summary": self.summary_rows()}
            ctx.out(json.dumps(strict_json(document), indent=2))
        elif self.reports:
            ctx.out(json.dumps(strict_json(self.reports[0]), indent=2))

    def end(self, ctx: CommandContext, failure: OSError | None = None) -> list[Path]:
        """Each directory marked as it was left (those whose mark could not be written,
        returned); ended early (a stop outside a strategy's frames, or ``failure``), the
        summary's rows of the flights not finished, and those never reached emptied of an
        earlier run's strategies."""
        unmarked = mark_each_ended(self.outs, EVAL_RUN, self.say(ctx), self.refused, failure)
        if failure is None and self.stopped_by is None:
            return unmarked
        why = "stopped" if failure is None else "ended by a write that failed"
        if len(self.started) > len(self.reports):  # the flight it was writing
            said = f"{why} as its files were written: see its {RUN_MARK}"
            writing = self.flights[len(self.reports) : len(self.reports) + 1]
            self.summary.extend(SummaryRow.not_run(writing, self.strategies, said))
        reached = len(self.started)  # every flight with a report was started first
        said = f"not run: the evaluation was {why} before this flight"
        self.summary.extend(SummaryRow.not_run(self.flights[reached:], self.strategies, said))
        for out in self.outs[len(self.started) :]:
            forget_strategies(out, self.strategies, log=FDR_LOG)
        return unmarked

    def finish(
        self, ctx: CommandContext, noted: Sequence[int], unmarked: Sequence[Path], *, as_json: bool
    ) -> int:
        """What it did said (:meth:`show`), and its exit status: 128 + the signal where Ctrl-C
        or SIGTERM (the last of ``noted``) stopped it, with the line that says where; 2 where a
        flight's mark could not be written (``unmarked``); else
        :func:`~c3_matcher_tools.run.evaluation.ended_status`."""
        self.show(ctx, as_json=as_json)
        in_frames = bool(self.reports) and not self.reports[-1]["complete"]
        if self.stopped_by is None and not in_frames:
            status = ended_status(self.summary, self.refused.values(), self.say(ctx))
            return EXIT_USAGE if unmarked else status
        signum = self.stopped_by if self.stopped_by is not None else noted[-1]
        word = "terminated" if signum == signal.SIGTERM else "interrupted"
        if in_frames:
            last = next(s for s in self.summary if s.stopped)
            report = self.outs[len(self.reports) - 1] / EVAL_RUN.report
            said = (
                f"during {last.strategy} on {last.flight}: {report} holds the strategies that "
                "finished and names those not run"
            )
        else:
            said = f"as its files were written: each flight's {RUN_MARK} says if it is complete"
        ctx.err(f"c3-matcher: {word} {said}")
        return 128 + signum
