"""What ``c3-matcher eval`` prints: each flight's table of the C3-IT measures, one row a
strategy (a strategy that failed to run, or was stopped, says so in its row), and the strategy
x flight summary of several flights."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher.context import CommandContext
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.dataset.sources.options import number_ranges
from c3_matcher_tools.run import figure
from c3_matcher_tools.run.acceptance import (
    BARS,
    IT01_BAR,
    IT03_BAR,
    IT04_BAR,
    WRONG_FIX_PX,
    Measure,
)
from c3_matcher_tools.run.evaluation import (
    StrategyEval,
    StrategyFailure,
    StrategyRow,
    StrategyStopped,
    SummaryRow,
)
from c3_matcher_tools.run.feature_sources import features_line
from c3_matcher_tools.run.outputs import EVAL_RUN
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.run.scoring import (
    attitude_noise_words,
    damaged_store_line,
    dropped_lines,
    telemetry_lines,
)

__all__ = ["print_flight_table", "print_summary_table", "say_dropped", "table_row"]


def print_flight_table(
    ctx: CommandContext,
    args: argparse.Namespace,
    name: str,
    report: dict[str, Any],
    rows: Sequence[StrategyRow],
    out: Path,
    max_keypoints: int | None,
) -> None:
    ctx.out(
        f"eval {name}: {report['frames']} frames "
        + (
            f"({report['absent_frames']} without the true tile)"
            if report["with_truth"]
            else "(no ground truth: the C3-IT figures need it; scored against the telemetry below)"
        )
        + f", max_keypoints {max_keypoints or 'each strategy its own'}"
        + attitude_noise_words({"sigma_deg": args.attitude_noise_deg})
    )
    ctx.out(
        f"{'strategy':18} {'IT-01 p5 inl':>13} {'IT-02':>7} {'IT-03 p95 px':>13} "
        f"{'IT-04 correct':>14} {'IT-05 raised':>13} {'false-conf':>10} {'other tile':>10} "
        f"{'frame p50/p95 ms':>17}"
    )
    for r in rows:
        ctx.out(table_row(r))
    ctx.out(
        "bars: "
        + "; ".join(f"{k} {v}" for k, v in BARS.items())
        + " ('!' = bar missed; n/a or x/0 = nothing to measure: neither passed nor missed)"
    )
    ctx.out(
        f"false-conf: picks whose inliers miss ground truth by > {WRONG_FIX_PX:g} px (bar: zero); "
        "other tile: picks of a candidate other than the true tile that still place the frame right"
    )
    _print_it04_case(ctx, rows)
    _print_unreadable(ctx, rows)
    _print_ambiguous(ctx, rows)
    _print_tiles_unread(ctx, rows)
    ctx.out(f"report {out / EVAL_RUN.report}, plots {out}")
    sources = {e["strategy"]: e.get("feature_sources") for e in report["strategies"]}
    for r in rows:
        if isinstance(r, StrategyEval):
            _print_links(ctx, r, sources.get(r.strategy))


def _print_it04_case(ctx: CommandContext, rows: Sequence[StrategyRow]) -> None:
    """Next to each strategy's C3-IT-04 verdict, the case its frames measured, and plainly
    where that is not the criterion's (:class:`~c3_matcher_tools.run.acceptance.CorrectTile`)."""
    for r in (r for r in rows if isinstance(r, StrategyEval)):
        it04, case = r.acceptance.correct_tile, r.acceptance.correct_tile.case
        if case is not None:
            verdict = {True: "pass", False: "missed", None: "nothing to measure"}[it04.passed]
            short = "" if case.shortfall is None else f": {case.shortfall}"
            ctx.out(f"{r.strategy}: C3-IT-04 {verdict} ({case.measured}){short}")


def _print_unreadable(ctx: CommandContext, rows: Sequence[StrategyRow]) -> None:
    """Say how many frames no measure counts: those whose image could not be read."""
    runs = [r.summary.count(FrameStatus.UNREADABLE) for r in rows if isinstance(r, StrategyEval)]
    if max(runs, default=0):
        ctx.out(
            f"{max(runs)} frame image(s) could not be read (the camera's loss, not the "
            "matcher's): no IT measure counts them"
        )


def _print_ambiguous(ctx: CommandContext, rows: Sequence[StrategyRow]) -> None:
    """Say, for each strategy that refused frames as ambiguous, how many and which: their
    inliers may pass the threshold, yet no fix was given."""
    for r in (r for r in rows if isinstance(r, StrategyEval)):
        if frames := r.summary.ambiguous_frames:
            ctx.out(
                f"{r.strategy}: {len(frames)} frame(s) ambiguous, no fix (a rival candidate "
                "with at least half the best's inliers places the frame elsewhere; raised, as "
                f"IT-05 and IT-01 count them): frames {number_ranges(frames)}"
            )


def _print_tiles_unread(ctx: CommandContext, rows: Sequence[StrategyRow]) -> None:
    """Say which absent-tile frames C3-IT-05 leaves out: every candidate dropped for its tile."""
    for r in (r for r in rows if isinstance(r, StrategyEval)):
        if unread := r.acceptance.absent_raised.tiles_unread_frames:
            ctx.out(
                f"{r.strategy}: IT-05 leaves out {len(unread)} frame(s) without the true tile "
                "whose every candidate was dropped for its tile (the matcher saw none): "
                + ", ".join(map(str, unread))
            )


def table_row(r: StrategyRow) -> str:
    if isinstance(r, StrategyFailure):
        return f"{r.strategy:18} failed to run: {r.error}"
    if isinstance(r, StrategyStopped):
        return f"{r.strategy:18} {r.error}"
    m, t = r.acceptance, r.summary

    def mark(measure: Measure) -> str:  # passed or nothing to measure (None): no mark
        return "!" if measure.passed is False else ""

    it1, it2, it3 = m.inlier_count, m.determinism.passed, m.inlier_error
    it4, it5, fc = m.correct_tile, m.absent_raised, m.false_confident
    cells = (
        IT01_BAR.figure(it1.p5_best_inliers) + mark(it1),
        "n/a" if it2 is None else "same" if it2 else "DIFF",
        IT03_BAR.figure(it3.p95_mean_error_px, 2) + mark(it3),
        f"{it4.correct}/{it4.frames}" + mark(it4),
        f"{it5.insufficient}/{it5.absent_frames}" + mark(it5),
        f"{fc.count}/{fc.of}" + mark(fc),
        str(len(fc.right_fix_other_tile)),
        f"{figure(t.frame_ms_p50, '.0f')}/{figure(t.frame_ms_p95, '.0f')}",
    )
    return (
        f"{r.strategy:18} {cells[0]:>13} {cells[1]:>7} {cells[2]:>13} {cells[3]:>14} "
        f"{cells[4]:>13} {cells[5]:>10} {cells[6]:>10} {cells[7]:>17}"
    )


def _print_links(ctx: CommandContext, r: StrategyEval, sources: dict[str, int] | None) -> None:
    """Under the table, a strategy's telemetry figures, where its candidates' features came
    from (``sources``: counts, as ``eval.json`` has them) and its files."""
    for line in telemetry_lines(r.summary) if r.summary.with_telemetry else ():
        ctx.out(f"  {r.strategy}: {line}")
    if sources is not None:
        ctx.out(f"  {r.strategy}: {features_line(sources)}")
    ctx.out(f"  {r.strategy}: map {r.geojson or '-'}, flight report {r.html or '-'}")


def print_summary_table(ctx: CommandContext, summary: Sequence[SummaryRow]) -> None:
    """The one strategy x flight table."""
    rows = sorted(summary, key=lambda s: (s.strategy, s.flight))
    w = max([20, *(len(s.flight) for s in rows)])  # the flight column fits every name
    ctx.out()
    ctx.out(
        f"{'strategy':18} {'flight':{w}} {'correct tile':>13} {'IT-03 p95':>10} {'IT-05':>7} "
        f"{'false-conf':>10} {'other tile':>10} {'ms/frame':>9}"
    )
    for s in rows:
        h = s.figures
        if h is None:
            said = s.error if s.stopped else f"failed to run: {s.error}"
            ctx.out(f"{s.strategy:18} {s.flight:{w}} {said}")
            continue
        rate = f"{h.correct}/{h.present}" if h.present else "-"
        it05 = f"{h.it05_raised}/{h.absent}"
        fc = f"{h.false_confident}/{h.scored}"
        ctx.out(
            f"{s.strategy:18} {s.flight:{w}} {rate:>13} "
            f"{IT03_BAR.figure(h.it03_p95_px, 2):>10} {it05:>7} "
            f"{fc:>10} {s.right_fix_other_tile:>10} {figure(s.frame_ms_p50, '.0f'):>9}"
        )
    for strategy in sorted({s.strategy for s in rows if s.figures is not None}):
        mine = [s.figures for s in rows if s.strategy == strategy and s.figures is not None]
        correct, present = sum(h.correct for h in mine), sum(h.present for h in mine)
        wrong, scored = sum(h.false_confident for h in mine), sum(h.scored for h in mine)
        rate = (
            f"{correct}/{present} ({IT04_BAR.figure(correct / present, percent=True)})"
            if present
            else "-"  # no frame with its true tile: as in the rows above
        )
        ctx.out(
            f"{strategy:18} {'all flights':{w}} {rate} correct tile, "
            f"{wrong}/{scored} false-confident"
        )


def say_dropped(
    ctx: CommandContext, json_out: bool, dataset: FlightDataset, rows: Sequence[StrategyRow]
) -> None:
    """What each strategy that ran dropped (:func:`dropped_lines`), under the table; with
    ``json_out`` (stdout is the JSON document) only that the tile store is damaged, on stderr."""
    for r in (r for r in rows if isinstance(r, StrategyEval)):
        if not json_out:
            for line in dropped_lines(r.summary, dataset.store_path):
                ctx.out(f"{r.strategy}: {line}")
        elif (damaged := damaged_store_line(r.summary, dataset.store_path)) is not None:
            ctx.err(f"c3-matcher eval: {r.strategy} on {dataset.name}: {damaged}")
