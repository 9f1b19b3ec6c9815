"""``c3-matcher eval DATASET``: every linked strategy and the classical OpenCV SIFT + MAGSAC
baseline, side by side, against a flight's ground truth (the C3-IT acceptance measures).

- C3-IT-01: best-candidate inlier count, p5 over the frames whose true tile is present (a frame
  that raised InsufficientInliersError counts 0, as the health window does); bar >= 80.
- C3-IT-02: determinism: a second run with a fresh matcher gives bit-identical per-frame results
  (:func:`c3_matcher_tools.replay.result_fingerprint`; ``--determinism-frames`` limits it to the
  first N frames); bar: every compared frame identical.
- C3-IT-03: per frame, the mean reprojection error of the best candidate's inliers against
  ground truth (ORIGINAL frame px); p95 over the matched true-present frames; bar < 2.5 px.
- C3-IT-04: correct-candidate rate (the best is the true tile) over true-present frames, with
  attitude tilt up to 20 deg and distractors >= 350 m away; bar >= 0.95 (this project's choice:
  the seeds name the case, not a rate).
- C3-IT-05: every frame whose true tile is absent raises InsufficientInliersError; bar: all.
- false-confident (beside IT-05): frames that returned a best candidate whose inliers
  put the frame in the wrong place: their mean error against ground truth (the same measure as
  IT-03, through the picked candidate's own ground-truth homography) is over
  ``WRONG_FIX_PX`` = 4x the IT-03 bar, or unknown; over all frames with ground truth; bar: none.
  A pick of an overlapping candidate that is not the true tile but places the frame right is
  not a wrong fix: it is counted apart (``right_fix_other_tile``), and IT-04 still scores it as
  not correct.

A recorded flight (no ground truth, ``dataset import``) is scored against its own telemetry:
per frame the estimate minus where the telemetry says the frame looks (m), p50/p95 beside the
GNSS accuracy the log states, and the frames whose GNSS was absent or degraded (``timing`` and
``per_frame`` in ``eval.json``).

Several datasets (``c3-matcher eval FLIGHT1 FLIGHT2 ...``) are evaluated one after the other
(outputs under ``--out/<dataset>``) and summarised in one strategy x flight table (correct-tile
rate, IT-03 p95, IT-05, false-confident, frame p50 ms), also written as ``summary.json``.

Writes ``eval.json``, per strategy ``<strategy>/results.jsonl`` (+ FDR and logs),
``<strategy>/flight.geojson`` and ``<strategy>/report.html`` (the same as ``replay`` writes), and
plots
(``inliers.png``, ``error.png``, ``matches/<strategy>_<frame>.png``) under ``--out`` (default
``out/eval/<dataset>``); stdout carries the table (or JSON with ``--json``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.commands import CommandRegistry
from c3_matcher.config import C3Settings
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset, with_attitude_noise
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.replay import (
    FrameOutcome,
    add_attitude_noise_option,
    build_matcher,
    run_flight,
    summarize,
    with_overrides,
    write_flight_outputs,
)

__all__ = [
    "BARS",
    "WRONG_FIX_PX",
    "evaluate_strategy",
    "is_wrong_fix",
    "metrics",
    "register_eval_command",
]

BARS = {
    "C3-IT-01": ">= 80 inliers (p5)",
    "C3-IT-02": "identical",
    "C3-IT-03": "< 2.5 px (p95)",
    "C3-IT-04": ">= 0.95",
    "C3-IT-05": "all absent frames",
}

IT03_BAR_PX = 2.5
WRONG_FIX_PX = 4 * IT03_BAR_PX
"""A returned pick is a wrong fix when its inliers' mean error against ground truth exceeds
this (ORIGINAL frame px): four times the IT-03 bar, a scale-free bound far below any
distractor's offset (>= 350 m, over 100 frame px on every shipped flight) and above the
per-inlier scatter of a right but imprecise fix (IT-03 means of 2-4 px across seasons)."""


def is_wrong_fix(outcome: FrameOutcome) -> bool:
    """A returned pick that places the frame wrong (see ``WRONG_FIX_PX``); a raise never is."""
    if outcome.status != "ok":
        return False
    error = outcome.mean_error_px
    return not (math.isfinite(error) and error <= WRONG_FIX_PX)


def metrics(run1: list[FrameOutcome], run2: list[FrameOutcome]) -> dict[str, Any]:
    """The C3-IT figures and pass flags of one strategy (see the module docstring)."""
    present = [o for o in run1 if o.has_truth and o.true_present]
    absent = [o for o in run1 if o.has_truth and not o.true_present]
    positions = [o.position_error_m for o in present if o.status == "ok"]
    positions = [p for p in positions if math.isfinite(p)]
    inliers = [float(o.best_inliers) for o in present]
    p5 = float(np.percentile(inliers, 5)) if inliers else math.nan
    errors = [
        o.mean_error_px for o in present if o.status == "ok" and math.isfinite(o.mean_error_px)
    ]
    p95 = float(np.percentile(errors, 95)) if errors else math.nan
    first = {o.index: o for o in run1}
    compared = [o for o in run2 if o.index in first]
    differing = [
        o.index
        for o in compared
        if (o.status, o.fingerprint) != (first[o.index].status, first[o.index].fingerprint)
    ]
    correct = sum(o.correct for o in present)
    rate = correct / len(present) if present else math.nan
    raised = sum(o.status == "insufficient" for o in absent)
    scored = [o for o in run1 if o.has_truth]
    wrong = [o.index for o in scored if is_wrong_fix(o)]
    right_elsewhere = [
        o.index for o in scored if o.status == "ok" and not o.correct and not is_wrong_fix(o)
    ]
    return {
        "C3-IT-01": {"p5_best_inliers": p5, "frames": len(present), "pass": p5 >= 80},
        "C3-IT-02": {
            "frames_compared": len(compared),
            "differing_frames": differing,
            "pass": bool(compared) and not differing,
        },
        "C3-IT-03": {
            "p95_mean_error_px": p95,
            "frames_scored": len(errors),
            "median_mean_error_px": float(np.median(errors)) if errors else math.nan,
            "p95_position_error_m": float(np.percentile(positions, 95)) if positions else math.nan,
            "median_position_error_m": float(np.median(positions)) if positions else math.nan,
            "pass": bool(errors) and p95 < IT03_BAR_PX,
        },
        "C3-IT-04": {
            "correct_rate": rate,
            "correct": correct,
            "frames": len(present),
            "pass": bool(present) and rate >= 0.95,
        },
        "C3-IT-05": {
            "insufficient": raised,
            "absent_frames": len(absent),
            "pass": raised == len(absent),
        },
        "false_confident": {
            "frames": wrong,
            "count": len(wrong),
            "of": len(scored),
            "rate": len(wrong) / len(scored) if scored else math.nan,
            "bound_px": WRONG_FIX_PX,
            "right_fix_other_tile": right_elsewhere,
            "pass": not wrong,
        },
    }


def evaluate_strategy(
    settings: C3Settings,
    strategy: str,
    dataset: FlightDataset,
    out: Path,
    determinism_frames: int | None,
) -> dict[str, Any]:
    """Run ``strategy`` twice over ``dataset`` (the second time on the first
    ``determinism_frames`` frames, all when None) and score it."""
    frames = list(dataset.frames)
    started = time.perf_counter()
    with build_matcher(settings, strategy, out / strategy) as matcher:
        startup_s = time.perf_counter() - started
        run1 = run_flight(matcher, dataset, progress=ProgressBar(f"eval {strategy} run 1"))
    wall_s = time.perf_counter() - started
    subset = frames[:determinism_frames] if determinism_frames else frames
    with build_matcher(settings, strategy, out / strategy / "run2") as matcher:
        run2 = run_flight(
            matcher, dataset, frames=subset, progress=ProgressBar(f"eval {strategy} run 2")
        )
    with (out / strategy / "results.jsonl").open("w", encoding="utf-8") as fh:
        for o in run1:
            fh.write(json.dumps(o.to_json()) + "\n")
    timing = summarize(run1)
    scores = metrics(run1, run2)
    flight: dict[str, Any] = {
        "dataset": str(dataset.root),
        "strategy": strategy,
        "matcher_labels": sorted({str(o.result["matcher_label"]) for o in run1 if o.result}),
        "settings": settings.matcher.model_copy(update={"strategy": strategy}).model_dump(
            mode="json"
        ),
        "startup_s": startup_s,
        "wall_s": wall_s,
        **timing,
        **{f"{k} pass": v["pass"] for k, v in scores.items()},
    }
    write_flight_outputs(out / strategy, dataset, run1, strategy, flight)
    return {
        "strategy": strategy,
        "startup_s": startup_s,
        "wall_s": wall_s,
        "timing": timing,
        "metrics": scores,
        "geojson": flight["geojson"],
        "html": flight["html"],
        "per_frame": [
            {
                "index": o.index,
                "status": o.status,
                "true_present": o.true_present,
                "best_inliers": o.best_inliers,
                "correct": o.correct,
                "mean_error_px": o.mean_error_px if math.isfinite(o.mean_error_px) else None,
                "telemetry_error_m": (
                    o.telemetry_error_m if math.isfinite(o.telemetry_error_m) else None
                ),
                "gnss_accuracy_m": o.gnss_accuracy_m,
                "gnss_degraded": o.gnss_degraded,
                "elapsed_ms": o.elapsed_ms,
            }
            for o in run1
        ],
        "_outcomes": run1,
    }


def _plots(
    dataset: FlightDataset, rows: list[dict[str, Any]], out: Path, samples: int
) -> list[str]:
    from c3_matcher.viz import draw_matches
    from c3_matcher_tools.plots import line_chart

    ok_rows = [r for r in rows if "error" not in r]
    written = [
        str(
            line_chart(
                out / "inliers.png",
                {
                    r["strategy"]: [float(f["best_inliers"]) for f in r["per_frame"]]
                    for r in ok_rows
                },
                title=f"{dataset.name}: best-candidate inliers per frame",
                ylabel="inliers",
                bar=80,
            )
        ),
        str(
            line_chart(
                out / "error.png",
                {
                    r["strategy"]: [
                        math.nan if f["mean_error_px"] is None else f["mean_error_px"]
                        for f in r["per_frame"]
                    ]
                    for r in ok_rows
                },
                title=f"{dataset.name}: mean inlier error vs ground truth per frame",
                ylabel="px",
                bar=2.5,
            )
        ),
    ]
    if samples <= 0:
        return written
    present = [f for f in dataset.frames if f.true_tile_present]
    positions = sorted(
        {round(k * (len(present) - 1) / max(samples - 1, 1)) for k in range(samples)}
    )
    picks = [present[p] for p in positions] if present else []
    with dataset.open_store() as store:
        for r in ok_rows:
            by_index = {o.index: o for o in r["_outcomes"]}
            for frame in picks:
                o = by_index.get(frame.index)
                if o is None or o.result is None or o.best_input_index is None:
                    continue
                best = o.result["per_candidate"][0]
                corr = np.asarray(best.get("inlier_correspondences", []), dtype=np.float32)
                cand = frame.candidates[o.best_input_index]
                tile = store.handle(cand.tile_id, dataset.candidate_size_px).decode()
                path = out / "matches" / f"{r['strategy']}_{frame.index:04d}.png"
                draw_matches(
                    dataset.nav_frame(frame).image,
                    tile,
                    corr.reshape(-1, 4),
                    path,
                    title=f"{r['strategy']} frame {frame.index}: {o.best_inliers} inliers, "
                    f"{'true tile' if o.correct else 'wrong tile'}, err {o.mean_error_px:.2f}px",
                    height=480,
                )
                written.append(str(path))
    return written


def register_eval_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "eval",
        help="C3-IT-01..05 for every linked strategy and the SIFT + MAGSAC baseline",
        description="Evaluate strategies side by side on a c3-flight/1 dataset against its "
        "ground truth (see c3_matcher_tools.evaluate). Table on stdout, progress on stderr.",
    )
    p.add_argument(
        "dataset",
        type=Path,
        nargs="+",
        help="dataset directory (holds dataset.json); several: one summary table at the end",
    )
    p.add_argument(
        "--strategy",
        action="append",
        default=None,
        help="strategy to evaluate (repeatable; default: every linked strategy)",
    )
    p.add_argument("--no-baseline", action="store_true", help="skip the SIFT + MAGSAC baseline")
    p.add_argument(
        "--out", type=Path, default=None, help="output directory (default out/eval/<dataset>)"
    )
    p.add_argument(
        "--max-keypoints", type=int, default=None, help="override [matcher] max_keypoints"
    )
    p.add_argument(
        "--determinism-frames",
        type=int,
        default=None,
        help="frames of the second (C3-IT-02) run (default: all)",
    )
    p.add_argument("--samples", type=int, default=3, help="match pictures per strategy (default 3)")
    add_attitude_noise_option(p)
    p.add_argument("--json", action="store_true", help="print eval.json instead of the table")
    p.set_defaults(handler=run_eval)


def _fmt(value: float, spec: str) -> str:
    return "n/a" if not math.isfinite(value) else format(value, spec)


def run_eval(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.compose import build_plugin_host

    datasets = [  # every path checked first
        with_attitude_noise(load_dataset(path), args.attitude_noise_deg) for path in args.dataset
    ]
    settings = with_overrides(settings, args.max_keypoints)
    specs = build_plugin_host().strategies()
    learned = sorted(n for n, spec in specs.items() if not spec.baseline)
    baselines = [] if args.no_baseline else sorted(n for n, s in specs.items() if s.baseline)
    names = [*(args.strategy or learned), *(b for b in baselines if b not in (args.strategy or []))]
    several = len(datasets) > 1
    summary: list[dict[str, Any]] = []
    for dataset in datasets:
        if several:
            out = (args.out or Path("out") / "eval") / dataset.name
        else:
            out = args.out or Path("out") / "eval" / dataset.name
        rows = _eval_dataset(args, settings, dataset, names, out)
        summary.extend(_summary_row(dataset.name, r) for r in rows)
    if several:
        root = args.out or Path("out") / "eval"
        (root / "summary.json").write_text(json.dumps(_finite(summary), indent=2) + "\n")
    if not args.json:
        _print_summary(summary)
    return 0


def _eval_dataset(
    args: argparse.Namespace,
    settings: C3Settings,
    dataset: FlightDataset,
    names: list[str],
    out: Path,
) -> list[dict[str, Any]]:
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for name in names:
        try:
            rows.append(evaluate_strategy(settings, name, dataset, out, args.determinism_frames))
        except Exception as exc:  # a strategy that cannot start is a row, not the end
            rows.append({"strategy": name, "error": f"{type(exc).__name__}: {exc}"})
    try:
        plots = _plots(dataset, rows, out, args.samples)
    except Exception as exc:  # the figures matter more than the pictures
        print(f"c3-matcher eval: plots failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        plots = []
    report = {
        "dataset": str(dataset.root),
        "frames": len(dataset.frames),
        "absent_frames": sum(f.has_truth and not f.true_tile_present for f in dataset.frames),
        "with_truth": sum(f.has_truth for f in dataset.frames),
        "attitude_noise": dataset.meta.get("attitude_noise"),
        "settings": settings.matcher.model_dump(mode="json"),
        "bars": BARS,
        "strategies": [{k: v for k, v in r.items() if k != "_outcomes"} for r in rows],
        "plots": plots,
    }
    (out / "eval.json").write_text(json.dumps(_finite(report), indent=2) + "\n")
    if args.json:
        print(json.dumps(_finite(report), indent=2))
        return rows
    print(
        f"eval {dataset.name}: {report['frames']} frames "
        + (
            f"({report['absent_frames']} without the true tile)"
            if report["with_truth"]
            else "(no ground truth: the C3-IT figures need it; scored against the telemetry below)"
        )
        + f", max_keypoints {settings.matcher.max_keypoints}"
        + (
            f", attitude noise {args.attitude_noise_deg:g} deg (1 sigma)"
            if args.attitude_noise_deg
            else ""
        )
    )
    print(
        f"{'strategy':18} {'IT-01 p5 inl':>13} {'IT-02':>7} {'IT-03 p95 px':>13} "
        f"{'IT-04 correct':>14} {'IT-05 raised':>13} {'false-conf':>10} {'other tile':>10} "
        f"{'frame p50/p95 ms':>17}"
    )
    for r in rows:
        if "error" in r:
            print(f"{r['strategy']:18} failed to run: {r['error']}")
            continue
        m, t = r["metrics"], r["timing"]

        def mark(key: str, m: dict[str, Any] = m) -> str:
            return "" if m[key]["pass"] else "!"

        it4, it5, fc = m["C3-IT-04"], m["C3-IT-05"], m["false_confident"]
        cells = (
            _fmt(m["C3-IT-01"]["p5_best_inliers"], ".0f") + mark("C3-IT-01"),
            "same" if m["C3-IT-02"]["pass"] else "DIFF",
            _fmt(m["C3-IT-03"]["p95_mean_error_px"], ".2f") + mark("C3-IT-03"),
            f"{it4['correct']}/{it4['frames']}" + mark("C3-IT-04"),
            f"{it5['insufficient']}/{it5['absent_frames']}" + mark("C3-IT-05"),
            f"{fc['count']}/{fc['of']}" + mark("false_confident"),
            str(len(fc["right_fix_other_tile"])),
            f"{t['frame_ms_p50']:.0f}/{t['frame_ms_p95']:.0f}",
        )
        print(
            f"{r['strategy']:18} {cells[0]:>13} {cells[1]:>7} {cells[2]:>13} {cells[3]:>14} "
            f"{cells[4]:>13} {cells[5]:>10} {cells[6]:>10} {cells[7]:>17}"
        )
    print("bars: " + "; ".join(f"{k} {v}" for k, v in BARS.items()) + " ('!' = bar missed)")
    print(
        f"false-conf: picks whose inliers miss ground truth by > {WRONG_FIX_PX:g} px (bar: none); "
        "other tile: picks of a candidate other than the true tile that still place the frame right"
    )
    print(f"report {out / 'eval.json'}, plots {out}")
    for r in rows:
        if "error" in r:
            continue
        t = r["timing"]
        if t["with_telemetry"]:
            print(
                f"  {r['strategy']}: estimate - telemetry position m p50 "
                f"{_fmt(t['telemetry_error_m_p50'] or math.nan, '.1f')}, p95 "
                f"{_fmt(t['telemetry_error_m_p95'] or math.nan, '.1f')} (GNSS accuracy stated "
                f"p50 {_fmt(t['gnss_accuracy_m_p50'] or math.nan, '.1f')} m, GNSS absent or "
                f"degraded on {len(t['gnss_degraded_frames'])} frame(s))"
            )
        print(f"  {r['strategy']}: map {r['geojson']}, flight report {r['html'] or '-'}")
    return rows


def _summary_row(flight: str, r: dict[str, Any]) -> dict[str, Any]:
    if "error" in r:
        return {"strategy": r["strategy"], "flight": flight, "error": r["error"]}
    m = r["metrics"]
    return {
        "strategy": r["strategy"],
        "flight": flight,
        "correct": m["C3-IT-04"]["correct"],
        "present": m["C3-IT-04"]["frames"],
        "it03_p95_px": m["C3-IT-03"]["p95_mean_error_px"],
        "it05_raised": m["C3-IT-05"]["insufficient"],
        "absent": m["C3-IT-05"]["absent_frames"],
        "false_confident": m["false_confident"]["count"],
        "scored": m["false_confident"]["of"],
        "right_fix_other_tile": len(m["false_confident"]["right_fix_other_tile"]),
        "frame_ms_p50": r["timing"]["frame_ms_p50"],
    }


def _print_summary(summary: list[dict[str, Any]]) -> None:
    """The one strategy x flight table."""
    print()
    print(
        f"{'strategy':18} {'flight':20} {'correct tile':>13} {'IT-03 p95':>10} {'IT-05':>7} "
        f"{'false-conf':>10} {'other tile':>10} {'ms/frame':>9}"
    )
    rows = sorted(summary, key=lambda s: (s["strategy"], s["flight"]))
    for s in rows:
        if "error" in s:
            print(f"{s['strategy']:18} {s['flight']:20} failed to run: {s['error']}")
            continue
        rate = f"{s['correct']}/{s['present']}" if s["present"] else "-"
        print(
            f"{s['strategy']:18} {s['flight']:20} {rate:>13} "
            f"{_fmt(s['it03_p95_px'], '.2f'):>10} {s['it05_raised']}/{s['absent']:<5} "
            f"{s['false_confident']}/{s['scored']:<7} {s['right_fix_other_tile']:>10} "
            f"{s['frame_ms_p50']:>9.0f}"
        )
    for strategy in sorted({s["strategy"] for s in rows if "error" not in s}):
        mine = [s for s in rows if s["strategy"] == strategy and "error" not in s]
        correct, present = sum(s["correct"] for s in mine), sum(s["present"] for s in mine)
        wrong, scored = sum(s["false_confident"] for s in mine), sum(s["scored"] for s in mine)
        share = f" ({correct / present:.0%})" if present else ""
        print(
            f"{strategy:18} {'all flights':20} {correct}/{present}{share} correct tile, "
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
