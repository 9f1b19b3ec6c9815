"""How ``c3-matcher eval`` ends: what it did so far (:class:`EvalRun`), said on stdout (one JSON
document, or the summary table) and answered with its exit status; stopped by a signal, the
line that says where; ended by a write that failed (a full disk, or stdout's reader gone), each
flight's directory marked as it was left (failed where its own file was the write refused,
complete where its report was written whole), those never reached emptied of an earlier run's
strategies, and what it did said all the same unless stdout is what failed."""

from __future__ import annotations

import json
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from c3_matcher.context import CommandContext
from c3_matcher_tools.eval_tables import print_summary_table
from c3_matcher_tools.run.evaluation import SummaryRow, ended_status, strict_json
from c3_matcher_tools.run.feature_sources import FDR_LOG
from c3_matcher_tools.run.forget import forget_strategies
from c3_matcher_tools.run.outputs import EVAL_RUN
from c3_matcher_tools.run.run_mark import mark_each_ended

__all__ = ["EvalRun"]


@dataclass
class EvalRun:
    """What an evaluation has done so far: the summary's rows (those a stop came before, not
    run), each dataset's report, by directory the write a full disk refused (None: none), and
    the directories it started. ``several``: it evaluates several datasets (its JSON document
    holds each one's report and the summary)."""

    several: bool
    summary: list[SummaryRow] = field(default_factory=list)
    reports: list[dict[str, Any]] = field(default_factory=list)
    refused: dict[Path, str | None] = field(default_factory=dict)
    started: list[Path] = field(default_factory=list)

    @staticmethod
    def say(ctx: CommandContext) -> Callable[[str], None]:
        """Say a line of the evaluation's on stderr."""
        return lambda line: ctx.err(f"c3-matcher eval: {line}")

    def summary_rows(self) -> list[Any]:
        """The summary's rows as ``summary.json`` holds them."""
        rows: list[Any] = strict_json([s.to_json() for s in self.summary])
        return rows

    def show(self, ctx: CommandContext, *, as_json: bool) -> None:
        """What it did, on stdout: one JSON document (the one dataset's ``eval.json``, or for
        several ``{"flights": [each one's eval.json, in order], "summary": summary.json's
        rows}``), else the summary table."""
        if not as_json:
            print_summary_table(ctx, self.summary)
            return
        document: Any = self.reports[0]
        if self.several:  # even when a stop came before the second
            document = {"flights": list(self.reports), "summary": self.summary_rows()}
        ctx.out(json.dumps(strict_json(document), indent=2))

    def finish(
        self, ctx: CommandContext, outs: Sequence[Path], noted: Sequence[int], *, as_json: bool
    ) -> int:
        """What it did said (:meth:`show`), and its exit status: 130 or 143 where Ctrl-C or
        SIGTERM (the last of ``noted``) stopped it, with the line that says where; else
        :func:`~c3_matcher_tools.run.evaluation.ended_status`."""
        self.show(ctx, as_json=as_json)
        if not self.reports[-1]["complete"]:
            last = next(s for s in self.summary if s.stopped)
            word = "terminated" if noted[-1] == signal.SIGTERM else "interrupted"
            report = outs[len(self.reports) - 1] / EVAL_RUN.report
            ctx.err(
                f"c3-matcher: {word} during {last.strategy} on {last.flight}: {report} holds "
                "the strategies that finished and names those not run"
            )
            return 128 + noted[-1]
        return ended_status(self.summary, self.refused.values(), self.say(ctx))

    def ended_by(
        self,
        exc: OSError,
        ctx: CommandContext,
        outs: Sequence[Path],
        names: Sequence[str],
        *,
        as_json: bool,
    ) -> None:
        """Ended by ``exc``, a write that failed: each of ``outs`` marked as it was left, those
        never reached emptied of an earlier run's ``names`` strategies, and what it did said
        (:meth:`show`) unless stdout is what failed (its reader gone)."""
        mark_each_ended(outs, EVAL_RUN, self.say(ctx), self.refused, exc)
        for out in outs[len(self.started) :]:
            forget_strategies(out, names, log=FDR_LOG)
        if self.reports and not isinstance(exc, BrokenPipeError):
            self.show(ctx, as_json=as_json)
