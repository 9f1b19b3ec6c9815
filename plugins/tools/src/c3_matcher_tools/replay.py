"""``c3-matcher replay DATASET``: every frame of a ``c3-flight/1`` dataset through the
composition root's matcher (or the SIFT + MAGSAC baseline), with a progress bar on stderr.

Writes under ``--out`` (default ``out/replay/<dataset>-<strategy>``; a dataset name that is not
one plain path component is refused): ``results.jsonl`` (one line per frame: status ``ok`` |
``insufficient`` (no fix: too few inliers, or, with an ``ambiguous`` key naming the rival, two
candidates placing the frame apart) | ``backbone_error`` | ``unreadable`` (its image could not be
read or decoded: the frame is recorded with the reason and the flight goes on), elapsed ms, the
scoring against ground truth and, for ``ok``, the MatchResult as ``c3-matcher match`` prints
it), ``fdr.jsonl`` (the flight-data records), ``matcher.log`` (the JSON logs), ``report.json``,
``flight.geojson`` (truth and estimate: centres, tracks, footprints; QGIS opens it) and
``report.html`` (the self-contained flight report, with the ``report`` extra: matplotlib), and
first ``run.json``,
which marks the directory as a replay's. A replay replaces an earlier replay's output; an
existing ``--out`` that is not empty and holds none (a flight-data log, a user's files, an
eval's output) is refused. The results and reports are each replaced atomically; the FDR and
log are started afresh only once this run holds the FDR's lock, so a replay into a directory
another one is writing is refused with its files untouched. The dataset is held while the
replay reads it: a ``--force`` import or render over it is refused meanwhile, and a replay
while one replaces it. What can refuse the run is checked
before ``--out`` is touched: every frame image (readable, of the calibration's size), every
noisy attitude (``--attitude-noise-deg``), an ``--out`` that is, holds or lies inside the
dataset or holds no earlier replay, the strategy and its engines (composed first). stdout
carries the report (a table, or JSON with ``--json``). Each ``ok`` result carries the best
homography and, the tile ids being georeferenced, the frame centre's lat/lon and its footprint;
frames with ground truth also carry ``truth_lat``/``truth_lon`` and ``position_error_m``: both
centres are the principal point's ground point, where the camera looks (under tilt, not the
point below the vehicle). The report's ``settings`` are the ``[matcher]`` settings the strategy
ran with (its own defaults where the configuration leaves a setting unset). The report counts
the candidates by where their features came from (``feature_sources``: ``stored``, ``cached``,
``extracted``, as the FDR's terminal records say); when the tile store has map features beside
it but the run was served none, a line on stderr says so and names the command that builds the
set the run asks for. Stopped by Ctrl-C or SIGTERM during the frames or its final writes, a
replay keeps the frames done: its ``run.json`` says how many (``complete``, ``frames_done``,
``frames_planned``), then ``results.jsonl`` and ``report.json`` hold them (with the map and
flight report only where they were written before the stop), the report on stdout says the
same and one line says so (exit 130/143). Until a run's files are written its ``run.json``
says ``"running": true`` (a run killed outright is told from one that ended); it also names
the dataset (resolved) and the strategy, and the default ``--out`` of a dataset is refused to
another of its name (exit 2). The report reaches stdout once the files are written, naming
those that were: a final write that fails (a full disk) still prints it, ``run.json`` then
saying ``"failed"`` (the file and why) in place of ``running``, and results not written name
the partial file that keeps the frames as they were flown (one that stops taking frames, the
disk full, says so once on stderr); a stdout that cannot be written (its reader gone, a full
disk under it) still leaves the files, and fails the command as it would have (exit 141, or 1
naming stdout).

The command only: flying and scoring are the run layer's (:mod:`c3_matcher_tools.run`).
"""

from __future__ import annotations

import argparse
import json
import signal
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher.commands import EXIT_OK, CommandRegistry, add_max_keypoints_option, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher.errors import OutputStreamError
from c3_matcher_tools.args import add_attitude_noise_option, apply_attitude_noise
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.dataset.lock import reading_dataset
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.dataset.provenance import say_import_faults
from c3_matcher_tools.dataset.sources.options import number_ranges
from c3_matcher_tools.features.command import GivenSettings, given_settings
from c3_matcher_tools.run import (
    REPLAY_OUT,
    FlightOptions,
    FlightRun,
    FlightStopped,
    Overrides,
    RunSummary,
    check_flight,
    check_output_dirs,
    exclusive_output_dir,
    figure,
    flight_report,
    fly_prepared,
    output_dir_name,
    prepare_matcher,
    signals_noted,
    summarize,
    write_flight_outputs,
    write_results,
)
from c3_matcher_tools.run.acceptance import WRONG_FIX_PX
from c3_matcher_tools.run.feature_sources import (
    FDR_LOG,
    FeatureSources,
    features_line,
    read_feature_sources,
    unserved_line,
)
from c3_matcher_tools.run.outputs import (
    REPLAY_RUN,
    RUN_FILES,
    mark_output_dirs,
    refuse_other_dataset,
)
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.run.results_file import RESULTS_FILE, kept_frames, partial_results
from c3_matcher_tools.run.run_mark import (
    RUN_MARK,
    mark_ended,
    mark_stopped,
    refused_write,
    say_ended,
)
from c3_matcher_tools.run.scoring import (
    attitude_noise_words,
    dropped_lines,
    status_line,
    telemetry_lines,
)

__all__ = ["register_replay_command", "run_replay"]


def register_replay_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "replay",
        help="run every frame of a flight dataset through the matcher (results, FDR, report)",
        description="Replay a flight dataset (what `dataset render` and `dataset import` write) "
        "through the configured matcher. Progress on stderr; the report on stdout.",
    )
    p.add_argument("dataset", type=Path, help="dataset directory (holds dataset.json)")
    p.add_argument(
        "--strategy",
        default=None,
        help="strategy (default: configuration); sift_magsac for the classical baseline",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help=f"output directory (default {REPLAY_OUT}/<dataset>-<strategy>)",
    )
    p.add_argument(
        "--limit", type=bounded_int(), default=None, help="only the first N frames (>= 1)"
    )
    add_max_keypoints_option(p)
    p.add_argument(
        "--no-correspondences",
        action="store_true",
        help="omit inlier correspondences from results.jsonl",
    )
    add_attitude_noise_option(p)
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(handler=run_replay)


def run_replay(args: argparse.Namespace, ctx: CommandContext) -> int:
    """Everything that can refuse the run (the dataset, its frames, the noisy attitudes,
    ``--out``, the strategy and its engines) is checked before ``--out`` is touched: a refused
    replay leaves an existing ``--out`` as it was and makes none. The dataset is held from
    the first read to the last file written (:func:`reading_dataset`): it is not replaced
    under the run, which reads its images frame by frame."""
    with reading_dataset(args.dataset):
        return _replay(args, ctx)


def _replay(args: argparse.Namespace, ctx: CommandContext) -> int:
    """:func:`run_replay`'s work, the dataset held."""
    settings = ctx.settings
    loaded = load_dataset(args.dataset, settings.matcher.max_image_pixels)
    dataset = apply_attitude_noise(loaded, args.attitude_noise_deg, args.limit)
    strategy = args.strategy or settings.matcher.strategy
    out = args.out or REPLAY_OUT / f"{output_dir_name(dataset)}-{strategy}"
    frames = list(dataset.frames[: args.limit] if args.limit else dataset.frames)
    check_flight(dataset, frames)
    check_output_dirs([out], [dataset], layout=REPLAY_RUN)
    if args.out is None:  # named after the dataset: another of its name may have written it
        refuse_other_dataset(out, dataset, REPLAY_RUN)
    say_import_faults(dataset, say=ctx.err)
    overrides = Overrides(max_keypoints=args.max_keypoints)
    with (
        prepare_matcher(
            settings, strategy, plugin_host=ctx.plugin_host, overrides=overrides
        ) as prepared,
        exclusive_output_dir(out),
    ):
        mark_output_dirs(REPLAY_RUN, out, datasets=[dataset], strategy=strategy)
        flown = FlightOptions(
            frames,
            ProgressBar(f"replay {dataset.name} {strategy}"),
            with_correspondences=not args.no_correspondences,
            keep_stopped=True,
        )
        run: FlightRun | None = None
        written: list[Path] = []  # the run's files, once every one is written
        with signals_noted() as noted:  # from the first frame to the last file written
            try:
                run = fly_prepared(
                    prepared, dataset, out, plugin_host=ctx.plugin_host, options=flown
                )
                given = given_settings(args.config)
                return _write_and_say(ctx, args.json, dataset, run, out, given, written)
            except FlightStopped as stop:
                run, signum = stop.run, stop.signum
            except KeyboardInterrupt:
                if run is None or not noted or written:  # nothing to keep, or all of it kept
                    raise
                signum = noted[-1]
        assert run is not None  # fly_prepared's FlightStopped holds the run
        return _keep_stopped(ctx, args.json, dataset, out, run, signum, given_settings(args.config))


def _write_and_say(
    ctx: CommandContext,
    as_json: bool,
    dataset: FlightDataset,
    run: FlightRun,
    out: Path,
    given: GivenSettings,
    written: list[Path],
) -> int:
    """The run's files (``report.json`` last, naming the others; ``written`` then holds them),
    then the report on stdout and the unserved line under ``given``, the settings the run was
    given. A write that fails (a full disk) still prints the report, naming the files that
    were written; a stdout that cannot be written (a reader gone, a full disk under it) is
    raised once the files are written, so that they are whatever happens to stdout."""
    summary = summarize(run.outcomes)
    features = read_feature_sources(out / FDR_LOG)  # once, for the report and the line
    report = _run_report(dataset, run, summary, out, features)
    try:
        files = write_flight_outputs(
            out, dataset, run, {**report, "geojson": str(out / "flight.geojson")}
        )
        report = {**report, "geojson": files.geojson, "html": files.html}
        write_text_atomically(out / REPLAY_RUN.report, json.dumps(report, indent=2) + "\n")
        mark_ended(out)  # its files are written: the run is no longer in progress
    except OSError as exc:  # the run ended: it says so, and what it wrote
        say_ended(out, lambda line: ctx.err(f"c3-matcher replay: {line}"), refused_write(exc, out))
        _say(ctx, as_json, dataset, run, out, {**report, **_files_there(out)}, features, given)
        raise
    written.extend(out / name for name in RUN_FILES)
    _say(ctx, as_json, dataset, run, out, report, features, given)
    return EXIT_OK


def _files_there(out: Path) -> dict[str, Any]:
    """The results, map and flight report this run wrote in ``out`` (an earlier run's were
    removed as it started), None for each not written; with no results, the frames kept as
    they were flown (``kept_as_flown``: the partial file and its frames) where there are any."""
    results = out / RESULTS_FILE
    there: dict[str, Any] = {
        name: str(path) if path.is_file() else None
        for name, path in (
            ("results", results),
            ("geojson", out / "flight.geojson"),
            ("html", out / "report.html"),
        )
    }
    if there["results"] is None and (kept := kept_frames(results)):
        there["kept_as_flown"] = {"file": str(partial_results(results)), "frames": kept}
    return there


def _say(
    ctx: CommandContext,
    as_json: bool,
    dataset: FlightDataset,
    run: FlightRun,
    out: Path,
    report: dict[str, Any],
    features: FeatureSources,
    given: GivenSettings,
) -> None:
    """``report`` on stdout, then the unserved line under ``given`` on stderr; a stdout that
    cannot be written raised after that line."""
    unsaid: OSError | OutputStreamError | None = None
    try:
        _print_report(ctx, as_json, dataset.name, report, summarize(run.outcomes), out)
    except (BrokenPipeError, OutputStreamError) as exc:
        unsaid = exc
    _say_unserved(ctx, dataset, run, features, given)
    if unsaid is not None:
        raise unsaid


def _say_unserved(
    ctx: CommandContext,
    dataset: FlightDataset,
    run: FlightRun,
    features: FeatureSources,
    given: GivenSettings,
) -> None:
    """On stderr, when the store has map features but the run (``features``: what its
    flight-data log says of them) was served none of them: what builds the set it asks for
    under ``given`` (:func:`unserved_line`)."""
    if (line := unserved_line(dataset, run, features, given)) is not None:
        ctx.err(line)


def _run_report(
    dataset: FlightDataset, run: FlightRun, summary: RunSummary, out: Path, features: FeatureSources
) -> dict[str, Any]:
    """``report.json`` but for the map and flight report: the run, whether it is whole, its
    figures, its files and where its candidates' features came from (``features``)."""
    return {
        **flight_report(dataset, run, summary),
        **run.progress,
        "attitude_noise": dataset.meta.get("attitude_noise"),
        "store": str(dataset.store_path),
        "results": str(out / "results.jsonl"),
        "fdr": str(out / FDR_LOG),
        "log": str(out / "matcher.log"),
        "log_lines_lost": run.log_lines_lost,
        "feature_sources": features.counts,
    }


def _print_report(
    ctx: CommandContext,
    as_json: bool,
    name: str,
    report: dict[str, Any],
    summary: RunSummary,
    out: Path,
) -> None:
    """The report on stdout, flushed: printed before the run's files are written, so that one
    that cannot be written (a full disk) still leaves the summary of the frames matched."""
    if as_json:
        ctx.out(json.dumps(report, indent=2))
    else:
        for line in _report_lines(name, report, summary, out):
            ctx.out(line)
    ctx.flush()


def _keep_stopped(
    ctx: CommandContext,
    as_json: bool,
    dataset: FlightDataset,
    out: Path,
    run: FlightRun,
    signum: int,
    given: GivenSettings,
) -> int:
    """A replay stopped by Ctrl-C or SIGTERM, part-way or while writing its files, keeps the
    frames it did: ``run.json`` says how many first, then their ``results.jsonl`` and
    ``report.json`` (naming the map and flight report where they were written before the
    stop), each written atomically (a second Ctrl-C meanwhile stops at once, tearing
    nothing); the report on stdout (as JSON or not), one line naming what is kept, and 130 or
    143 as a shell reports the signal; the unserved line under ``given``, the settings the run
    was given."""
    mark_stopped(REPLAY_RUN, out, run)
    results = write_results(out / "results.jsonl", run.outcomes)
    summary = summarize(run.outcomes)
    features = read_feature_sources(out / FDR_LOG)
    report = {**_run_report(dataset, run, summary, out, features), **_files_there(out)}
    write_text_atomically(out / REPLAY_RUN.report, json.dumps(report, indent=2) + "\n")
    _print_report(ctx, as_json, dataset.name, report, summary, out)
    _say_unserved(ctx, dataset, run, features, given)
    word = "terminated" if signum == signal.SIGTERM else "interrupted"
    done, planned = report["frames_done"], report["frames_planned"]
    whole = "" if run.complete else f" ({RUN_MARK} marks the run incomplete)"
    ctx.err(
        f"c3-matcher: {word} after {done} of {planned} frames: their results are in {results}"
        + whole
    )
    return 128 + signum


def _truth_lines(s: RunSummary) -> list[str]:
    """What the run came to against ground truth: the correct candidates, the wrong fixes
    among the frames scored (as eval's false-conf counts them: picks whose inliers miss the
    ground truth by more than ``WRONG_FIX_PX``) and the frames without their true tile that
    raised (the right answer there)."""
    if not s.frames:
        return ["  no frame done: nothing scored"]
    if not s.with_truth:
        return ["  no ground truth in this flight: nothing scored against truth"]
    wrong = s.false_confident_frames
    lines = [
        f"  correct candidate {s.correct_candidate}/{s.true_present} "
        "frames with the true tile present",
        f"  false-conf {s.false_confident}/{s.scored} frames: picks whose inliers miss ground "
        f"truth by > {WRONG_FIX_PX:g} px (bar: zero)"
        + (f"; frames {number_ranges(wrong)}" if wrong else ""),
    ]
    if s.true_absent:
        lines.append(
            f"  raised on {s.absent_raised}/{s.true_absent} frames without their true tile "
            "(InsufficientInliersError, too few inliers or ambiguous, is the right answer there)"
        )
    return lines


def _report_lines(name: str, report: dict[str, Any], s: RunSummary, out: Path) -> list[str]:
    """The table: ``s``'s figures, and the run, tile store and files ``report`` names."""
    unreadable = s.count(FrameStatus.UNREADABLE)
    lines = [
        f"replay {name} with {report['strategy']}: {s.frames} frames in "
        f"{report['wall_s']:.1f} s (startup {report['startup_s']:.1f} s)"
        + attitude_noise_words(report.get("attitude_noise")),
        f"  {status_line(s)}",
    ]
    dropped = dropped_lines(s, report.get("store", "of the dataset"))  # then the store if failed
    lines.extend(f"  {line}" for line in dropped[:1])
    if s.frames - unreadable - s.true_absent > 0 and not s.count(FrameStatus.OK):
        lines.append(
            "  no frame matched: "
            + (
                dropped[1]
                if len(dropped) > 1
                else "check that the store covers the flight and that heights and attitudes are "
                "right; `c3-matcher eval` compares the strategies on it"
            )
        )
    elif len(dropped) > 1:
        lines.append(f"  {dropped[1]}")
    lines.extend(_truth_lines(s))
    lines.append(
        f"  frame ms p50 {figure(s.frame_ms_p50, '.0f')}, p95 {figure(s.frame_ms_p95, '.0f')}"
    )
    if (sources := report.get("feature_sources")) is not None:
        lines.append(f"  {features_line(sources)}")
    if s.georeferenced and s.with_truth:
        lines.append(
            f"  position error m p50 {figure(s.position_error_m_p50)}, "
            f"p95 {figure(s.position_error_m_p95)} over every matched frame "
            f"({s.position_error_frames} frames; {s.georeferenced} located)"
        )
    if s.with_telemetry:
        lines.extend(f"  {line}" for line in telemetry_lines(s))
    saved = out / REPLAY_RUN.report
    lines.append(
        f"  results {report['results'] or _unwritten_results(report)}, FDR {report['fdr']}, "
        f"report {saved if saved.is_file() else '(not written)'}"
    )
    lines.append(
        f"  map {report['geojson'] or '(not written)'}, "
        f"flight report {report['html'] or '(not written)'}"
    )
    if lost := report.get("log_lines_lost"):
        lines.append(f"  {report['log']}: {lost} line(s) could not be written (a full disk?)")
    return lines


def _unwritten_results(report: dict[str, Any]) -> str:
    """What the table says of results not written: where the frames kept as flown are."""
    kept = report.get("kept_as_flown")
    where = f"; the first {kept['frames']} frame(s) in {kept['file']}" if kept else ""
    return f"(not written{where})"
