"""``c3-matcher eval DATASET``: every linked strategy and the classical OpenCV SIFT + MAGSAC
baseline, side by side, against a flight's ground truth (the C3-IT acceptance measures).

- C3-IT-01: best-candidate inlier count, p5 over the frames whose true tile is present (a frame
  that raised InsufficientInliersError counts 0, as the health window does); bar >= 80.
- C3-IT-02: determinism: a second run with a fresh matcher gives bit-identical per-frame results
  (:func:`c3_matcher_tools.run.result_fingerprint`; ``--determinism-frames`` limits it to the
  first N frames); bar: every compared frame identical.
- C3-IT-03: per frame, the mean reprojection error of the best candidate's inliers against
  ground truth (ORIGINAL frame px); p95 over the matched true-present frames; bar < 2.5 px.
- C3-IT-04: correct-candidate rate (the best is the true tile) over true-present frames; bar
  >= 0.95 (this project's choice: the specification names the case, tilt up to 20 deg with
  distractors >= 350 m away, not a rate). Beside it, the case the flight's frames measured (the
  largest tilt of the attitude the matcher was given, the nearest distractor from the true
  tile; ``case`` in ``eval.json``, a line under the table), said plainly where it is not the
  criterion's (zurich_z16, manila_grey_z19, gorinchem_z18: < 10 deg, distractors 40-150 m).
- C3-IT-05: every frame whose true tile is absent raises InsufficientInliersError; bar: all.
  A frame whose every candidate was dropped for its tile (a damaged tile store) raised without
  the matcher seeing a tile: IT-05 counts it neither as raised nor as absent, but names it
  apart (``tiles_unread_frames``), and a line under the table says so.
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
rate, IT-03 p95, IT-05, false-confident, frame p50 ms), also written as ``summary.json`` (each
row with the candidates given and those dropped for their tiles, ``tile_dropped``). A later eval
of one of those flights alone into its folder (``--out <root>/<dataset>``; ``out/eval/<dataset>``
without ``--out``) replaces that flight's rows of the summary with its own, said on stderr (where
the folder now holds another flight, it removes the summary): no row names figures that the
folders beside it do not hold. With ``--json`` stdout carries one JSON document (the line that
says a tile store is damaged goes to stderr): a single dataset's ``eval.json``; for several,
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
is touched) writes nothing there and leaves what an earlier run wrote. An output directory another
process is writing (its FDR lock held) stops the command at once: nothing more is written into
it; so does an output directory another ``eval`` or ``replay`` holds (each holds its
directories, ``--out`` and each dataset's, while it runs). Ctrl-C or SIGTERM stops it at
once, keeping what finished: the earlier datasets whole, this dataset's ``eval.json`` with the
strategies done, the one stopped (the frames of its first run done, in its ``results.jsonl``;
stopped as its files were written, its figures whole, naming the files not written) and those
not run (``"complete": false``, ``"not_run"``), ``summary.json`` and the tables so far; exit
130 or 143. Each dataset is held while the run reads it: a ``--force`` import or render over
it is refused meanwhile, and the run is refused while one replaces it.

Writes ``eval.json``, per strategy ``<strategy>/results.jsonl`` (+ FDR and logs),
``<strategy>/flight.geojson`` and ``<strategy>/report.html`` (the same as ``replay`` writes, each
replaced atomically), and plots
(``inliers.png``, ``error.png``, ``matches/<strategy>_<frame>.png``) under ``--out`` (default
``out/eval/<dataset>``); stdout carries the table (or JSON with ``--json``). Each strategy's
entry in ``eval.json`` records the ``[matcher]`` settings it ran with (its own defaults where
the configuration leaves a setting unset), the keypoint budget it kept (``keypoint_budget``,
the number even where ``max_keypoints`` is unset) and its ``provenance`` (c3-matcher version,
matcher labels, execution provider and engines, as its FDR and ``report.html`` name them) and
its candidates counted by where their features came from (``feature_sources``, also under the
table); a store with map features of which a strategy was served none is said on stderr, with
the command that builds the set it asks for. Every dataset's earlier ``eval.json``, charts,
match pictures and what eval wrote in the directories of the strategies it names but this run
does not run (a file of the user's stays) are removed before the first dataset runs; each
strategy this run runs replaces its own as it starts, one that cannot start keeps it, and a
stopped run removes those of the strategies and flights it never reached: a stopped run, or
one of fewer strategies, leaves none of them looking like its own.

The command only: flying, scoring and the C3-IT measures are the run layer's
(:mod:`c3_matcher_tools.run`, :mod:`c3_matcher_tools.run.acceptance`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher.commands import (
    CommandRegistry,
    add_max_keypoints_option,
    bounded_int,
)
from c3_matcher.config import C3Settings
from c3_matcher.context import CommandContext
from c3_matcher.errors import describe
from c3_matcher.fdr import FdrOpenError
from c3_matcher.plugins.manager import PluginHost
from c3_matcher_tools.args import (
    add_attitude_noise_option,
    add_strategies_option,
    apply_attitude_noise,
)
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.dataset.lock import reading_dataset
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.dataset.provenance import say_import_faults
from c3_matcher_tools.eval_end import EvalRun
from c3_matcher_tools.eval_tables import print_flight_table, say_dropped
from c3_matcher_tools.features.command import given_settings
from c3_matcher_tools.run import (
    EVAL_OUT,
    NO_OVERRIDES,
    FlightOptions,
    FlightStopped,
    Overrides,
    check_flight,
    check_output_dirs,
    exclusive_output_dir,
    fly,
    forget_previous_run,
    signals_noted,
    summarize,
    write_results,
)
from c3_matcher_tools.run.acceptance import BARS, WRONG_FIX_PX, is_wrong_fix, metrics
from c3_matcher_tools.run.eval_dirs import eval_output_dirs
from c3_matcher_tools.run.evaluation import (
    StrategyEval,
    StrategyFailure,
    StrategyRow,
    StrategyStopped,
    SummaryRow,
    WritingStopped,
    strict_json,
    was_stopped,
    write_strategy_files,
)
from c3_matcher_tools.run.feature_sources import FDR_LOG, unserved_line
from c3_matcher_tools.run.forget import forget_earlier_strategies, forget_not_reached
from c3_matcher_tools.run.outputs import (
    EVAL_RUN,
    EVAL_SUMMARY,
    mark_output_dirs,
    no_report_html,
    refuse_other_dataset,
    summary_above,
    write_summary,
)

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
    ``determinism_frames`` frames, all when None) and score it (no report.html: the run says).
    Ctrl-C or SIGTERM in the first run's frames raises :class:`FlightStopped` with those done;
    in the second or its scoring, with the whole first run; as its files are written,
    :class:`WritingStopped` with its figures."""
    frames = list(dataset.frames)
    run1 = fly(
        settings,
        strategy,
        dataset,
        out / strategy,
        plugin_host=plugin_host,
        overrides=overrides,
        options=FlightOptions(progress=ProgressBar(f"eval {strategy} run 1"), keep_stopped=True),
    )
    subset = frames[:determinism_frames] if determinism_frames else frames
    try:
        run2 = fly(
            settings,
            strategy,
            dataset,
            out / strategy / "run2",
            plugin_host=plugin_host,
            overrides=overrides,
            options=FlightOptions(subset, ProgressBar(f"eval {strategy} run 2")),
        )
    except KeyboardInterrupt as exc:  # the first run is whole: it is kept
        done = run1.outcomes
        raise FlightStopped(signal.SIGINT, done, len(done), run1) from exc
    try:
        summary = summarize(run1.outcomes)
        acceptance = metrics(run1.outcomes, run2.outcomes, dataset.frames)
    except KeyboardInterrupt as exc:  # as in the second run: the first is kept
        done = run1.outcomes
        raise FlightStopped(signal.SIGINT, done, len(done), run1) from exc
    return write_strategy_files(out / strategy, dataset, run1, acceptance, summary)


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
    written) when a strategy failed to run on a dataset; 130 or 143 when Ctrl-C or SIGTERM
    stopped it (:func:`_eval_dataset`: what finished is kept, the tables say what did not).
    Each dataset is held from the first read to the end (:func:`reading_dataset`): none is
    replaced under the run, which reads its images frame by frame."""
    with contextlib.ExitStack() as held:
        for path in args.dataset:
            held.enter_context(reading_dataset(path))
        return _eval(args, ctx)


def _eval(args: argparse.Namespace, ctx: CommandContext) -> int:
    """:func:`run_eval`'s work, its datasets held."""
    limit = ctx.settings.matcher.max_image_pixels
    datasets = [  # every input checked before anything runs or any directory is made
        apply_attitude_noise(load_dataset(path, limit), args.attitude_noise_deg)
        for path in args.dataset
    ]
    for dataset in datasets:  # its tile store opens; each frame image readable, of its size
        check_flight(dataset, dataset.frames)
    names = _strategies(args, ctx.plugin_host)
    outs = eval_output_dirs(args.out, datasets)
    root = (args.out or EVAL_OUT) if len(datasets) > 1 else None
    check_output_dirs(outs, datasets, layout=EVAL_RUN, root=root)  # before anything runs
    if args.out is None:  # folders named after the datasets
        for dataset, out in zip(datasets, outs, strict=True):
            refuse_other_dataset(out, dataset, EVAL_RUN)
    above = None if root is not None else summary_above(outs[0], EVAL_RUN)
    held = [root] if root is not None else ([] if above is None else [above.path.parent])
    say_import_faults(*datasets, say=ctx.err)
    if (no_report := no_report_html()) is not None:  # once a run, not once a strategy
        ctx.err(no_report)
    with exclusive_output_dir(*held, *outs), signals_noted() as noted:
        mark_output_dirs(EVAL_RUN, *outs, datasets=datasets)
        above = summary_above(outs[0], EVAL_RUN) if above else None  # read again, held
        for summarised in held:  # written again as the run ends
            forget_previous_run(summarised, (EVAL_SUMMARY,))
        _forget_earlier_reports(outs, names)  # every flight's, before the first runs
        run = EvalRun([d.name for d in datasets], outs, names, several=root is not None)
        failure: OSError | None = None
        try:
            _eval_datasets(args, ctx, datasets, noted, run)
            rows = run.summary_rows()
            if (said := write_summary(rows, root, above, datasets[0].name)) is not None:
                ctx.err(f"c3-matcher eval: {said}")
        except KeyboardInterrupt:  # a stop outside a strategy's frames: its files were written
            if not noted:
                raise
            run.stopped_by = noted[-1]
        except OSError as exc:  # a full disk, or stdout's reader gone
            failure = exc
        unmarked = run.end(ctx, failure)
    if failure is not None:
        if not isinstance(failure, BrokenPipeError):  # what it did, said all the same
            run.show(ctx, as_json=args.json)
        raise failure
    return run.finish(ctx, noted, unmarked, as_json=args.json)


def _eval_datasets(
    args: argparse.Namespace,
    ctx: CommandContext,
    datasets: Sequence[FlightDataset],
    noted: Sequence[int],
    run: EvalRun,
) -> None:
    """Each of ``datasets`` through every strategy, into its directory of ``run.outs``, until
    a stop, ``run`` saying what was done as it goes."""
    names, outs = list(run.strategies), run.outs
    for n, (dataset, out) in enumerate(zip(datasets, outs, strict=True)):
        run.started.append(out)
        rows, report = _eval_dataset(args, ctx, dataset, names, out, noted)
        run.refused[out] = StrategyFailure.unwritten_of(rows)
        run.reports.append(report)
        run.summary.extend(SummaryRow.of(dataset.name, r) for r in rows)
        if not report["complete"]:
            run.summary.extend(SummaryRow.not_run([d.name for d in datasets[n + 1 :]], names))
            forget_not_reached(out, rows, report["not_run"], outs[n + 1 :], names)
            break


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


def _eval_dataset(
    args: argparse.Namespace,
    ctx: CommandContext,
    dataset: FlightDataset,
    names: list[str],
    out: Path,
    noted: Sequence[int],
) -> tuple[list[StrategyRow], dict[str, Any]]:
    """``dataset`` through every strategy: the rows and the report written as ``eval.json``
    (its table printed unless ``--json``). Stopped by a signal in ``noted`` part-way, the report
    of the strategies finished, the one stopped and those not run (``complete`` false; no
    plots)."""
    from c3_matcher_tools.plots import eval_plots

    overrides = Overrides(max_keypoints=args.max_keypoints)
    rows = _eval_strategies(ctx, args.determinism_frames, dataset, names, out, overrides, noted)
    complete = not any(was_stopped(r) for r in rows)
    ran = [r.run for r in rows if isinstance(r, StrategyEval)]
    try:
        plots = eval_plots(dataset, ran, out, args.samples if complete else 0)
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
        "complete": complete,
        "not_run": names[len(rows) :],
        "strategies": [r.to_json() for r in rows],
        "plots": plots,
    }
    write_text_atomically(out / EVAL_RUN.report, json.dumps(strict_json(report), indent=2) + "\n")
    if not args.json:
        max_keypoints = overrides.apply(ctx.settings).matcher.max_keypoints
        print_flight_table(ctx, args, dataset.name, report, rows, out, max_keypoints)
    say_dropped(ctx, args.json, dataset, rows)
    given = given_settings(args.config)  # the settings the build a line names must run with
    for r in rows:
        if not isinstance(r, StrategyEval) or r.features is None:
            continue
        if (line := unserved_line(dataset, r.run, r.features, given)) is not None:
            ctx.err(line)
    return rows, report


def _forget_earlier_reports(outs: Sequence[Path], names: Sequence[str]) -> None:
    """What an earlier eval left in each of ``outs`` (the run files in the directories of the
    strategies it names but this run's ``names``, its ``eval.json``, charts and match
    pictures), removed before the first dataset runs: a run stopped part-way leaves none of
    them looking like its own (with ``forget_not_reached``)."""
    from c3_matcher_tools.plots import CHARTS, forget_match_pictures

    for out in outs:
        forget_earlier_strategies(out, names, log=FDR_LOG)  # named by its eval.json: first
        forget_previous_run(out, (EVAL_RUN.report, *(f"{chart}.png" for chart in CHARTS)))
        forget_match_pictures(out)  # this run draws its own samples


def _eval_strategies(
    ctx: CommandContext,
    determinism_frames: int | None,
    dataset: FlightDataset,
    names: list[str],
    out: Path,
    overrides: Overrides,
    noted: Sequence[int],
) -> list[StrategyRow]:
    """Each of ``names`` evaluated on ``dataset`` in turn (one that fails is a row, not the
    end), up to the one a signal in ``noted`` stops: its row keeps the frames it did."""
    rows: list[StrategyRow] = []
    for name in names:
        try:
            rows.append(
                evaluate_strategy(
                    ctx.settings,
                    name,
                    dataset,
                    out,
                    determinism_frames,
                    plugin_host=ctx.plugin_host,
                    overrides=overrides,
                )
            )
        except FdrOpenError:  # another process writes this directory: leave it to that run
            raise
        except Exception as exc:  # a strategy that cannot start is a row, not the end
            rows.append(StrategyFailure.of(name, exc))
        except KeyboardInterrupt as stop:
            if not noted:
                raise
            rows.append(_stopped(out / name, name, stop))
            break
    return rows


def _stopped(directory: Path, name: str, stop: KeyboardInterrupt) -> StrategyRow:
    """The row of strategy ``name`` that ``stop`` stopped: the frames of its first run done (all
    of them when the stop came in its second), written to ``directory``'s ``results.jsonl``;
    its figures where the stop came as its files were written."""
    if isinstance(stop, WritingStopped):
        return stop.row
    run = stop.run if isinstance(stop, FlightStopped) else None
    if run is None:
        return StrategyStopped(name)
    results = write_results(directory / "results.jsonl", run.outcomes)
    planned = len(run.outcomes) if run.planned is None else run.planned
    return StrategyStopped(name, len(run.outcomes), planned, str(results))
