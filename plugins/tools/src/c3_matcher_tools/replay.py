"""``c3-matcher replay DATASET``: every frame of a ``c3-flight/1`` dataset through the
composition root's matcher (or the SIFT + MAGSAC baseline), with a progress bar on stderr.

Writes under ``--out`` (default ``out/replay/<dataset>-<strategy>``; a dataset name that is not
one plain path component is refused): ``results.jsonl`` (one line per frame: status ``ok`` |
``insufficient`` | ``backbone_error`` | ``unreadable`` (its image could not be read or decoded:
the frame is recorded with the reason and the flight goes on), elapsed ms, the scoring against
ground truth and, for ``ok``, the MatchResult as ``c3-matcher match`` prints it), ``fdr.jsonl``
(the flight-data records), ``matcher.log`` (the JSON logs), ``report.json``, ``flight.geojson``
(truth and estimate: centres, tracks, footprints; QGIS opens it) and ``report.html`` (the
self-contained flight report, with the ``report`` extra: matplotlib), and first ``run.json``,
which marks the directory as a replay's. A replay replaces an earlier replay's output; an
existing ``--out`` that is not empty and holds none (a flight-data log, a user's files, an
eval's output) is refused. The results and reports are each replaced atomically; the FDR and
log are started afresh only once this run holds the FDR's lock, so a replay into a directory
another one is writing is refused with its files untouched. What can refuse the run is checked
before ``--out`` is touched: every frame image (readable, of the calibration's size), every
noisy attitude (``--attitude-noise-deg``), an ``--out`` that is, holds or lies inside the
dataset or holds no earlier replay, the strategy and its engines (composed first). stdout
carries the report (a table, or JSON with ``--json``). Each ``ok`` result carries
the best homography and, the tile ids being georeferenced, the frame centre's lat/lon and its
footprint; frames with ground truth also carry ``truth_lat``/``truth_lon`` and
``position_error_m``: both centres are the principal point's ground point, where the camera
looks (under tilt, not the point below the vehicle). The report's ``settings`` are the
``[matcher]`` settings the strategy ran with (its own defaults where the configuration leaves a
setting unset).

The command only: flying and scoring are the run layer's (:mod:`c3_matcher_tools.run`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher.commands import EXIT_OK, CommandRegistry, add_max_keypoints_option, bounded_int
from c3_matcher.context import CommandContext
from c3_matcher_tools.args import add_attitude_noise_option, apply_attitude_noise
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.run import (
    REPLAY_OUT,
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
    summarize,
    write_flight_outputs,
)
from c3_matcher_tools.run.outputs import REPLAY_RUN, mark_output_dirs
from c3_matcher_tools.run.records import FrameStatus

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
    replay leaves an existing ``--out`` as it was and makes none."""
    settings = ctx.settings
    loaded = load_dataset(args.dataset, settings.matcher.max_image_pixels)
    dataset = apply_attitude_noise(loaded, args.attitude_noise_deg, args.limit)
    strategy = args.strategy or settings.matcher.strategy
    out = args.out or REPLAY_OUT / f"{output_dir_name(dataset)}-{strategy}"
    frames = list(dataset.frames[: args.limit] if args.limit else dataset.frames)
    check_flight(dataset, frames)
    check_output_dirs([out], [dataset], layout=REPLAY_RUN)
    overrides = Overrides(max_keypoints=args.max_keypoints)
    with (
        prepare_matcher(
            settings, strategy, plugin_host=ctx.plugin_host, overrides=overrides
        ) as prepared,
        exclusive_output_dir(out),
    ):
        mark_output_dirs(REPLAY_RUN, out)
        run = fly_prepared(
            prepared,
            dataset,
            out,
            plugin_host=ctx.plugin_host,
            frames=frames,
            progress=ProgressBar(f"replay {dataset.name} {strategy}"),
            with_correspondences=not args.no_correspondences,
        )
        summary = summarize(run.outcomes)
        run_report = {
            **flight_report(dataset, run, summary),
            "attitude_noise": dataset.meta.get("attitude_noise"),
            "results": str(out / "results.jsonl"),
            "fdr": str(out / "fdr.jsonl"),
            "log": str(out / "matcher.log"),
        }
        files = write_flight_outputs(out, dataset, run, run_report)
        report = {**run_report, "geojson": files.geojson, "html": files.html}
        write_text_atomically(out / REPLAY_RUN.report, json.dumps(report, indent=2) + "\n")
    if args.json:
        ctx.out(json.dumps(report, indent=2))
        return EXIT_OK
    for line in _report_lines(dataset.name, report, summary, out):
        ctx.out(line)
    return EXIT_OK


def _report_lines(name: str, report: dict[str, Any], s: RunSummary, out: Path) -> list[str]:
    """The table: ``s``'s figures, and the run and files ``report`` names."""
    unreadable = s.count(FrameStatus.UNREADABLE)
    lines = [
        f"replay {name} with {report['strategy']}: {s.frames} frames in "
        f"{report['wall_s']:.1f} s (startup {report['startup_s']:.1f} s)",
        f"  ok {s.count(FrameStatus.OK)}, insufficient inliers "
        f"{s.count(FrameStatus.INSUFFICIENT)}, backbone errors "
        f"{s.count(FrameStatus.BACKBONE_ERROR)}"
        + (f", unreadable images {unreadable}" if unreadable else ""),
    ]
    if s.frames - unreadable - s.true_absent > 0 and not s.count(FrameStatus.OK):
        lines.append(
            "  no frame matched: check that the store covers the flight and that heights and "
            "attitudes are right; `c3-matcher eval` compares the strategies on it"
        )
    if s.with_truth:
        lines.append(
            f"  correct candidate {s.correct_candidate}/{s.true_present} "
            "frames with the true tile present"
        )
    else:
        lines.append("  no ground truth in this flight: nothing scored against truth")
    if s.true_absent:
        lines.append(
            f"  raised on {s.absent_raised}/{s.true_absent} frames without their true tile "
            "(InsufficientInliersError is the right answer there)"
        )
    lines.append(
        f"  frame ms p50 {figure(s.frame_ms_p50, '.0f')}, p95 {figure(s.frame_ms_p95, '.0f')}"
    )
    if s.georeferenced and s.with_truth:
        lines.append(
            f"  position error m p50 {figure(s.position_error_m_p50)}, "
            f"p95 {figure(s.position_error_m_p95)} over every matched frame "
            f"({s.position_error_frames} frames; {s.georeferenced} located)"
        )
    if s.with_telemetry:
        lines.append(_telemetry_line(s))
    lines.append(
        f"  results {report['results']}, FDR {report['fdr']}, report {out / REPLAY_RUN.report}"
    )
    lines.append(f"  map {report['geojson']}, flight report {report['html'] or '(not written)'}")
    return lines


def _telemetry_line(s: RunSummary) -> str:
    degraded = list(s.gnss_degraded_frames)
    accuracy = s.gnss_accuracy_m_p50
    return (
        f"  estimate - telemetry look point m p50 {figure(s.telemetry_error_m_p50)}, "
        f"p95 {figure(s.telemetry_error_m_p95)} ({s.georeferenced} frames "
        "located; "
        + ("GNSS accuracy not stated" if accuracy is None else f"GNSS accuracy {accuracy:.1f} m")
        + f"; GNSS absent or degraded on {len(degraded)} frame(s)"
        + (f": {degraded[:20]})" if degraded else ")")
    )
