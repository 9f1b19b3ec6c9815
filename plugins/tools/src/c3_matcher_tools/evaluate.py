"""``c3-matcher eval DATASET``: every linked strategy and the classical OpenCV SIFT + MAGSAC
baseline, side by side, against a flight's ground truth (the C3-IT acceptance measures).

- C3-IT-01: best-candidate inlier count, p5 over the frames whose true tile is present (a frame
  that raised InsufficientInliersError counts 0, as the health window does); bar >= 80.
- C3-IT-02: determinism: a second run with a fresh matcher gives bit-identical per-frame results
  (:func:`c3_matcher_tools.run.result_fingerprint`; ``--determinism-frames`` limits it to the
  first N frames); bar: every compared frame identical.
- C3-IT-03: per frame, the mean reprojection error of the best candidate's inliers against
  ground truth (ORIGINAL frame px); p95 over the matched true-present frames; bar < 2.5 px.
- C3-IT-04: correct-candidate rate (the best is the true tile) over true-present frames, with
  attitude tilt up to 20 deg and distractors >= 350 m away; bar >= 0.95 (this project's choice:
  the specification names the case, not a rate).
- C3-IT-05: every frame whose true tile is absent raises InsufficientInliersError; bar: all.
- false-confident (beside IT-05): frames that returned a best candidate whose inliers
  put the frame in the wrong place: their mean error against ground truth (the same measure as
  IT-03, through the picked candidate's own ground-truth homography) is over
  ``WRONG_FIX_PX`` = 4x the IT-03 bar, or unknown; over all frames with ground truth; bar: zero.
  A pick of an overlapping candidate that is not the true tile but places the frame right is
  not a wrong fix: it is counted apart (``right_fix_other_tile``), and IT-04 still scores it as
  not correct.

A recorded flight (no ground truth, ``dataset import``) is scored against its own telemetry:
per frame the estimate minus where the telemetry says the frame looks (m), p50/p95 over the
frames whose attitude was measured beside the GNSS accuracy the log states, the frames whose GNSS
was absent or degraded, and apart those whose attitude the import assumed level, with their own
p50 (``timing`` and ``per_frame`` in ``eval.json``).

Each measure's ``pass`` is true (bar met), false (bar missed, '!' in the table) or null: nothing
to measure (no true-tile frame, no matched one, no absent frame, no ground truth), neither
passed nor missed. A figure judged against a bar is printed so that it never contradicts the
bar (:meth:`~c3_matcher_tools.run.acceptance.Bar.figure`).

Several datasets (``c3-matcher eval FLIGHT1 FLIGHT2 ...``) are evaluated one after the other
(outputs under ``--out/<dataset>``) and summarised in one strategy x flight table (correct-tile
rate, IT-03 p95, IT-05, false-confident, frame p50 ms), also written as ``summary.json``. With
``--json`` stdout carries one JSON document: a single dataset's ``eval.json``; for several,
``{"flights": [each dataset's eval.json, in order], "summary": summary.json's rows}``. A
dataset name that names an output directory must be one plain path component, and several
datasets need as many names (refused before anything runs, exit 2, as are a strategy this build
cannot run, a frame image missing, unreadable or of another size than its calibration's (as
``replay`` checks them), a noisy attitude out of range (``--attitude-noise-deg``) and an output
directory that is, holds or lies inside a dataset, or holds something but no earlier eval's
output (marked ``run.json``): nothing is made or written then). A frame whose
image turns out damaged mid-run is that frame's ``unreadable`` status; the flight goes on, no
IT measure counts it (the camera's loss, not the matcher's), and a line under the table says so.

A strategy that fails to run on a dataset (it cannot start) is a table row and an ``error``
entry, the others go on, and the command exits 1 once every table and
report is written; one that cannot start (a missing engine: it is composed before its directory
is touched) leaves its directory as an earlier eval left it. An output directory another
process is writing (its FDR lock held) stops the command at once: nothing more is written into
it; so does an output directory another ``eval`` or ``replay`` holds (each holds its
directories, ``--out`` and each dataset's, while it runs).

Writes ``eval.json``, per strategy ``<strategy>/results.jsonl`` (+ FDR and logs),
``<strategy>/flight.geojson`` and ``<strategy>/report.html`` (the same as ``replay`` writes, each
replaced atomically), and plots
(``inliers.png``, ``error.png``, ``matches/<strategy>_<frame>.png``) under ``--out`` (default
``out/eval/<dataset>``); stdout carries the table (or JSON with ``--json``). Each strategy's
entry in ``eval.json`` records the ``[matcher]`` settings it ran with (its own defaults where
the configuration leaves a setting unset).

The command only: flying, scoring and the C3-IT measures are the run layer's
(:mod:`c3_matcher_tools.run`, :mod:`c3_matcher_tools.run.acceptance`).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher.commands import (
    EXIT_FAILURE,
    EXIT_OK,
    CommandRegistry,
    add_max_keypoints_option,
    bounded_int,
)
from c3_matcher.config import C3Settings
from c3_matcher.context import CommandContext
from c3_matcher.errors import InvalidInputError, describe
from c3_matcher.fdr import FdrOpenError
from c3_matcher.plugins.manager import PluginHost
from c3_matcher_tools.args import (
    add_attitude_noise_option,
    add_strategies_option,
    apply_attitude_noise,
)
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.run import (
    EVAL_OUT,
    NO_OVERRIDES,
    FlightOptions,
    Overrides,
    check_flight,
    check_output_dirs,
    exclusive_output_dir,
    figure,
    flight_report,
    fly,
    forget_previous_run,
    output_dir_name,
    summarize,
    write_flight_outputs,
)
from c3_matcher_tools.run.acceptance import (
    BARS,
    IT01_BAR,
    IT03_BAR,
    IT04_BAR,
    WRONG_FIX_PX,
    Measure,
    is_wrong_fix,
    metrics,
)
from c3_matcher_tools.run.evaluation import StrategyEval, StrategyFailure, StrategyRow, SummaryRow
from c3_matcher_tools.run.outputs import EVAL_RUN, EVAL_SUMMARY, mark_output_dirs, no_report_html
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.run.scoring import dropped_lines, telemetry_lines

__all__ = [
    "BARS",
    "WRONG_FIX_PX",
    "StrategyEval",
    "StrategyFailure",
    "SummaryRow",
    "evaluate_strategy",
    "is_wrong_fix",
    "metrics",
    "register_eval_command",
]


def evaluate_strategy(
    settings: C3Settings,
    strategy: str,
    dataset: FlightDataset,
    out: Path,
    determinism_frames: int | None,
    *,
    plugin_host: PluginHost,
    overrides: Overrides = NO_OVERRIDES,
) -> StrategyEval:
    """Run ``strategy`` twice over ``dataset`` (the second time on the first
    ``determinism_frames`` frames, all when None) and score it (no report.html: the run says)."""
    frames = list(dataset.frames)
    run1 = fly(
        settings,
        strategy,
        dataset,
        out / strategy,
        plugin_host=plugin_host,
        overrides=overrides,
        options=FlightOptions(progress=ProgressBar(f"eval {strategy} run 1")),
    )
    subset = frames[:determinism_frames] if determinism_frames else frames
    run2 = fly(
        settings,
        strategy,
        dataset,
        out / strategy / "run2",
        plugin_host=plugin_host,
        overrides=overrides,
        options=FlightOptions(subset, ProgressBar(f"eval {strategy} run 2")),
    )
    summary = summarize(run1.outcomes)
    acceptance = metrics(run1.outcomes, run2.outcomes)
    flight = {
        **flight_report(dataset, run1, summary),
        **{f"{k} pass": v.passed for k, v in acceptance.measures().items()},
    }
    files = write_flight_outputs(out / strategy, dataset, run1, flight, say_no_report=False)
    return StrategyEval(run1, acceptance, summary, files.geojson, files.html)


def register_eval_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "eval",
        help="accuracy of every linked strategy on flight datasets (the C3-IT-01..05 checks), "
        "beside the SIFT + MAGSAC baseline",
        description="Evaluate every linked strategy side by side on c3-flight/1 datasets against "
        "their ground truth, then the SIFT + MAGSAC baseline. Table on stdout, progress on stderr.",
    )
    p.add_argument(
        "dataset",
        type=Path,
        nargs="+",
        help="dataset directory (holds dataset.json); several: one summary table at the end",
    )
    add_strategies_option(p, "strategy to evaluate (repeatable; default: every linked strategy)")
    p.add_argument("--no-baseline", action="store_true", help="skip the SIFT + MAGSAC baseline")
    p.add_argument(
        "--out", type=Path, default=None, help=f"output directory (default {EVAL_OUT}/<dataset>)"
    )
    add_max_keypoints_option(p)
    p.add_argument(
        "--determinism-frames",
        type=bounded_int(),
        default=None,
        help="the first N frames (>= 1) in the second (C3-IT-02) run (default: all)",
    )
    p.add_argument(
        "--samples",
        type=bounded_int(0),
        default=3,
        help="match pictures per strategy (>= 0; 0: none; default 3)",
    )
    add_attitude_noise_option(p)
    p.add_argument(
        "--json",
        action="store_true",
        help="print one JSON document instead of the tables: eval.json for one dataset; for "
        'several, {"flights": [each dataset\'s eval.json], "summary": summary.json\'s rows}',
    )
    p.set_defaults(handler=run_eval)


def run_eval(args: argparse.Namespace, ctx: CommandContext) -> int:
    """Every dataset through every strategy; ``EXIT_FAILURE`` (the tables and reports still
    written) when a strategy failed to run on a dataset."""
    limit = ctx.settings.matcher.max_image_pixels
    datasets = [  # every input checked before anything runs or any directory is made
        apply_attitude_noise(load_dataset(path, limit), args.attitude_noise_deg)
        for path in args.dataset
    ]
    for dataset in datasets:  # its tile store opens; each frame image readable, of its size
        check_flight(dataset, dataset.frames)
    names = _strategies(args, ctx.plugin_host)
    outs = _output_dirs(args.out, datasets)
    root = (args.out or EVAL_OUT) if len(datasets) > 1 else None
    check_output_dirs(outs, datasets, layout=EVAL_RUN, root=root)  # before anything runs
    if (no_report := no_report_html()) is not None:  # once a run, not once a strategy
        ctx.err(no_report)
    summary: list[SummaryRow] = []
    reports: list[dict[str, Any]] = []
    with exclusive_output_dir(*([] if root is None else [root]), *outs):
        mark_output_dirs(EVAL_RUN, *outs)
        if root is not None:
            forget_previous_run(root, (EVAL_SUMMARY,))
        for dataset, out in zip(datasets, outs, strict=True):
            rows, report = _eval_dataset(args, ctx, dataset, names, out)
            reports.append(report)
            summary.extend(SummaryRow.of(dataset.name, r) for r in rows)
        summary_rows = [s.to_json() for s in summary]
        if root is not None:
            summary_json = json.dumps(_finite(summary_rows), indent=2) + "\n"
            write_text_atomically(root / EVAL_SUMMARY, summary_json)
    if args.json:
        ctx.out(json.dumps(_finite(_json_document(reports, summary_rows)), indent=2))
    else:
        _print_summary(ctx, summary)
    failed = [f"{s.strategy} on {s.flight}" for s in summary if s.figures is None]
    if failed:
        ctx.err(f"c3-matcher eval: failed to run: {', '.join(failed)}")
        return EXIT_FAILURE
    return EXIT_OK


def _json_document(
    reports: Sequence[dict[str, Any]], summary: Sequence[dict[str, Any]]
) -> dict[str, Any]:
    """What ``--json`` prints, one document: the one dataset's ``eval.json``, or for several
    ``{"flights": [each one's eval.json, in order], "summary": summary.json's rows}``."""
    if len(reports) == 1:
        return reports[0]
    return {"flights": list(reports), "summary": list(summary)}


def _strategies(args: argparse.Namespace, host: PluginHost) -> list[str]:
    """The strategies to run, in order: those ``--strategy`` names (each resolved first, so
    one this build cannot run is refused before anything runs), else every linked one; then
    the baseline unless ``--no-baseline``."""
    for name in args.strategy or []:
        host.resolve(name)
    specs = host.strategies()
    learned = sorted(n for n, spec in specs.items() if not spec.baseline)
    baselines = [] if args.no_baseline else sorted(n for n, s in specs.items() if s.baseline)
    return list(dict.fromkeys([*(args.strategy or learned), *baselines]))


def _output_dirs(out: Path | None, datasets: Sequence[FlightDataset]) -> list[Path]:
    """Each dataset's output directory: ``--out`` itself for a single dataset, else
    ``<--out or out/eval>/<dataset name>``; a name that is not one plain path component, or
    two datasets of one name (one would overwrite the other), are refused."""
    if len(datasets) == 1 and out is not None:
        return [out]
    names = [output_dir_name(d) for d in datasets]
    for n, name in enumerate(names):
        if name in names[:n]:
            first = datasets[names.index(name)].root
            raise InvalidInputError(
                "dataset",
                f"{first} and {datasets[n].root} are both named {name!r} (dataset.json "
                '"name"); their outputs would share one directory: give each its own name',
            )
    return [(out or EVAL_OUT) / name for name in names]


def _eval_dataset(
    args: argparse.Namespace,
    ctx: CommandContext,
    dataset: FlightDataset,
    names: list[str],
    out: Path,
) -> tuple[list[StrategyRow], dict[str, Any]]:
    """``dataset`` through every strategy: the rows and the report written as ``eval.json``
    (its table printed unless ``--json``)."""
    from c3_matcher_tools.plots import CHARTS, eval_plots, forget_match_pictures

    out.mkdir(parents=True, exist_ok=True)
    forget_previous_run(out, (EVAL_RUN.report, *(f"{chart}.png" for chart in CHARTS)))
    forget_match_pictures(out)  # this run draws its own samples
    overrides = Overrides(max_keypoints=args.max_keypoints)
    rows: list[StrategyRow] = []
    for name in names:
        try:
            rows.append(
                evaluate_strategy(
                    ctx.settings,
                    name,
                    dataset,
                    out,
                    args.determinism_frames,
                    plugin_host=ctx.plugin_host,
                    overrides=overrides,
                )
            )
        except FdrOpenError:  # another process writes this directory: leave it to that run
            raise
        except Exception as exc:  # a strategy that cannot start is a row, not the end
            rows.append(StrategyFailure(name, describe(exc)))
    ran = [r.run for r in rows if isinstance(r, StrategyEval)]
    try:
        plots = eval_plots(dataset, ran, out, args.samples)
    except Exception as exc:  # the figures matter more than the pictures
        ctx.err(f"c3-matcher eval: plots failed: {describe(exc)}")
        plots = []
    report = {
        "dataset": str(dataset.root),
        "frames": len(dataset.frames),
        "absent_frames": sum(f.has_truth and not f.true_tile_present for f in dataset.frames),
        "with_truth": sum(f.has_truth for f in dataset.frames),
        "attitude_noise": dataset.meta.get("attitude_noise"),
        "bars": BARS,
        "strategies": [r.to_json() for r in rows],
        "plots": plots,
    }
    write_text_atomically(out / EVAL_RUN.report, json.dumps(_finite(report), indent=2) + "\n")
    if not args.json:
        max_keypoints = overrides.apply(ctx.settings).matcher.max_keypoints
        _print_table(ctx, args, dataset.name, report, rows, out, max_keypoints)
        for r in (r for r in rows if isinstance(r, StrategyEval)):  # and what each dropped
            for line in dropped_lines(r.summary, dataset.store_path):
                ctx.out(f"{r.strategy}: {line}")
    return rows, report


def _print_table(
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
        + (
            f", attitude noise {args.attitude_noise_deg:g} deg (1 sigma)"
            if args.attitude_noise_deg
            else ""
        )
    )
    ctx.out(
        f"{'strategy':18} {'IT-01 p5 inl':>13} {'IT-02':>7} {'IT-03 p95 px':>13} "
        f"{'IT-04 correct':>14} {'IT-05 raised':>13} {'false-conf':>10} {'other tile':>10} "
        f"{'frame p50/p95 ms':>17}"
    )
    for r in rows:
        ctx.out(_table_row(r))
    ctx.out(
        "bars: "
        + "; ".join(f"{k} {v}" for k, v in BARS.items())
        + " ('!' = bar missed; n/a or x/0 = nothing to measure: neither passed nor missed)"
    )
    ctx.out(
        f"false-conf: picks whose inliers miss ground truth by > {WRONG_FIX_PX:g} px (bar: zero); "
        "other tile: picks of a candidate other than the true tile that still place the frame right"
    )
    _print_unreadable(ctx, rows)
    ctx.out(f"report {out / EVAL_RUN.report}, plots {out}")
    for r in rows:
        if isinstance(r, StrategyEval):
            _print_links(ctx, r)


def _print_unreadable(ctx: CommandContext, rows: Sequence[StrategyRow]) -> None:
    """Say how many frames no measure counts: those whose image could not be read."""
    runs = [r.summary.count(FrameStatus.UNREADABLE) for r in rows if isinstance(r, StrategyEval)]
    if max(runs, default=0):
        ctx.out(
            f"{max(runs)} frame image(s) could not be read (the camera's loss, not the "
            "matcher's): no IT measure counts them"
        )


def _table_row(r: StrategyRow) -> str:
    if isinstance(r, StrategyFailure):
        return f"{r.strategy:18} failed to run: {r.error}"
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


def _print_links(ctx: CommandContext, r: StrategyEval) -> None:
    for line in telemetry_lines(r.summary) if r.summary.with_telemetry else ():
        ctx.out(f"  {r.strategy}: {line}")
    ctx.out(f"  {r.strategy}: map {r.geojson}, flight report {r.html or '-'}")


def _print_summary(ctx: CommandContext, summary: Sequence[SummaryRow]) -> None:
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
            ctx.out(f"{s.strategy:18} {s.flight:{w}} failed to run: {s.error}")
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


def _finite(value: Any) -> Any:
    """NaN / inf -> None, recursively (strict JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value
