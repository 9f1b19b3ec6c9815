"""``c3-matcher replay DATASET``: every frame of a ``c3-flight/1`` dataset through the
composition root's matcher (or the SIFT + MAGSAC baseline), with a progress bar on stderr.

Writes under ``--out`` (default ``out/replay/<dataset>-<strategy>``): ``results.jsonl`` (one line
per frame: status ``ok`` | ``insufficient`` | ``backbone_error``, elapsed ms, the scoring against
ground truth and, for ``ok``, the MatchResult as ``c3-matcher match`` prints it), ``fdr.jsonl``
(the flight-data records), ``matcher.log`` (the JSON logs), ``report.json``, ``flight.geojson``
(truth and estimate: centres, tracks, footprints; QGIS opens it) and ``report.html`` (the
self-contained flight report, with the ``report`` extra: matplotlib); stdout carries the report
(a table, or JSON with ``--json``). Each ``ok`` result carries the best homography and, the tile
ids being georeferenced, the frame centre's lat/lon and its footprint; frames with ground truth
also carry ``truth_lat``/``truth_lon`` and ``position_error_m``.

:func:`run_flight` and :func:`build_matcher` are shared with ``c3-matcher eval``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher import camera as cam
from c3_matcher.commands import CommandRegistry
from c3_matcher.config import C3Settings
from c3_matcher.dto import MatchResult
from c3_matcher.errors import InsufficientInliersError, InvalidInputError, MatcherBackboneError
from c3_matcher.georef import haversine_m
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.serialize import result_to_json
from c3_matcher_tools.dataset.format import (
    FlightDataset,
    FrameRecord,
    load_dataset,
    with_attitude_noise,
)
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.dataset.truth import inlier_errors_px

__all__ = [
    "FrameOutcome",
    "build_matcher",
    "register_replay_command",
    "result_fingerprint",
    "run_flight",
    "summarize",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class FrameOutcome:
    """One frame's outcome. ``best_input_index``: input position of the best candidate;
    ``correct``: the best is the true tile; ``mean_error_px``: mean inlier error of the best
    candidate against ground truth (ORIGINAL frame px), NaN when not matched; ``fingerprint``:
    blake2b of the per-frame result content (C3-IT-02), excluding ``matched_at``.
    ``telemetry_lat``/``telemetry_lon``: where the flight's own telemetry (GNSS position,
    attitude, height) says the frame's centre looks; ``telemetry_error_m``: the estimate's
    distance from it (m, NaN when either is missing); ``gnss_accuracy_m``: the horizontal
    accuracy the log states for that fix; ``gnss_degraded``: GNSS was absent or degraded at the
    frame (None: no telemetry, or it does not say)."""

    index: int
    frame_id: str
    status: str
    elapsed_ms: float
    true_present: bool
    best_inliers: int
    best_input_index: int | None
    correct: bool
    mean_error_px: float
    residual_px: float
    fingerprint: str
    error: str | None
    result: dict[str, Any] | None
    has_truth: bool = True
    est_lat: float | None = None
    est_lon: float | None = None
    truth_lat: float | None = None
    truth_lon: float | None = None
    position_error_m: float = math.nan
    insufficient_best: int = 0
    telemetry_lat: float | None = None
    telemetry_lon: float | None = None
    telemetry_error_m: float = math.nan
    gnss_accuracy_m: float | None = None
    gnss_degraded: bool | None = None

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("mean_error_px", "residual_px", "position_error_m", "telemetry_error_m"):
            if not math.isfinite(out[key]):
                out[key] = None
        return out


def result_fingerprint(result: MatchResult | None, insufficient_best: int = 0) -> str:
    """Bit-for-bit digest of ``per_candidate`` (tile ids, counts, residual float bits,
    correspondence bytes), ``best_candidate_idx`` and the input order; for an
    InsufficientInliersError, of its best inlier count."""
    h = hashlib.blake2b(digest_size=16)
    if result is None:
        h.update(f"insufficient:{insufficient_best}".encode())
        return h.hexdigest()
    h.update(str(result.best_candidate_idx).encode())
    h.update(repr(result.diagnostics.get("input_index")).encode())
    for c in result.per_candidate:
        h.update(repr((c.tile_id.as_list(), c.inlier_count, c.ransac_outlier_count)).encode())
        h.update(np.float64(c.per_candidate_residual_px).tobytes())
        h.update(c.inlier_correspondences.tobytes())
    return h.hexdigest()


def truth_position(dataset: FlightDataset, frame: FrameRecord) -> tuple[float, float] | None:
    """(lat, lon) where the frame's principal point truly looks: through the true candidate's
    ground-truth homography, else the record's ``pose`` footprint centre; None without truth."""
    from c3_matcher.georef import tile_px_to_lonlat

    k = dataset.calibration.K
    for cand in frame.candidates:
        if cand.is_true and cand.h_tile_to_undistorted is not None:
            size = dataset.candidate_size_px
            tile_px = cam.apply_homography(
                np.linalg.inv(cand.h_tile_to_undistorted), [[k[0, 2], k[1, 2]]]
            )
            lon, lat = tile_px_to_lonlat(cand.tile_id, (size, size), tile_px)[0]
            return float(lat), float(lon)
    pose = frame.pose
    if frame.has_truth and "footprint_centre_lat" in pose and "footprint_centre_lon" in pose:
        return float(pose["footprint_centre_lat"]), float(pose["footprint_centre_lon"])
    return None


def telemetry_reference(frame: FrameRecord) -> dict[str, Any]:
    """The frame's telemetry reference for :class:`FrameOutcome`: where the recorded position,
    attitude and height put the frame's centre (the import's look point), the stated GNSS
    accuracy and the degraded flag; empty without telemetry."""
    t = frame.telemetry
    if "look_lat" not in t or "look_lon" not in t:
        return {}
    accuracy = t.get("gnss_accuracy_m")
    return {
        "telemetry_lat": float(t["look_lat"]),
        "telemetry_lon": float(t["look_lon"]),
        "gnss_accuracy_m": None if accuracy is None else float(accuracy),
        "gnss_degraded": None if "gnss_degraded" not in t else bool(t["gnss_degraded"]),
    }


def _score(dataset: FlightDataset, frame: FrameRecord, result: MatchResult) -> tuple[int, float]:
    best_input = int(result.diagnostics["input_index"][0])
    cand = frame.candidates[best_input]
    if cand.h_tile_to_undistorted is None:
        return best_input, math.nan
    errors = inlier_errors_px(
        cand.h_tile_to_undistorted,
        dataset.calibration,
        result.per_candidate[0].inlier_correspondences,
    )
    return best_input, float(np.mean(errors)) if errors.size else math.nan


def run_flight(
    matcher: CrossDomainMatcher,
    dataset: FlightDataset,
    *,
    frames: list[FrameRecord] | None = None,
    progress: Progress | None = None,
    with_correspondences: bool = True,
) -> list[FrameOutcome]:
    """Match every frame (or ``frames``) in order; tiles are read lazily from the store."""
    todo = list(dataset.frames if frames is None else frames)
    outcomes: list[FrameOutcome] = []
    with dataset.open_store() as store:
        for n, frame in enumerate(todo, start=1):
            nav = dataset.nav_frame(frame)
            rerank = dataset.rerank(frame, store)
            t0 = time.perf_counter()
            error: str | None = None
            result: MatchResult | None = None
            best_count = 0
            try:
                result = matcher.match(nav, rerank, dataset.calibration)
                status = "ok"
            except InsufficientInliersError as exc:
                status, best_count, error = "insufficient", exc.best_inlier_count, str(exc)
            except MatcherBackboneError as exc:
                status, error = "backbone_error", str(exc)
            elapsed = (time.perf_counter() - t0) * 1e3
            truth = truth_position(dataset, frame)
            geo_truth: dict[str, Any] = {"has_truth": frame.has_truth}
            if truth is not None:
                geo_truth.update(truth_lat=truth[0], truth_lon=truth[1])
            geo_truth.update(telemetry_reference(frame))
            if result is not None:
                best_input, mean_err = _score(dataset, frame, result)
                size = dataset.candidate_size_px
                as_json = result_to_json(
                    result,
                    with_correspondences=with_correspondences,
                    calibration=dataset.calibration,
                    tile_sizes=[(size, size)] * len(frame.candidates),
                )
                if "centre_lat" in as_json:
                    geo_truth.update(est_lat=as_json["centre_lat"], est_lon=as_json["centre_lon"])
                    if truth is not None:
                        geo_truth["position_error_m"] = float(
                            haversine_m(
                                [[as_json["centre_lon"], as_json["centre_lat"]]],
                                [[truth[1], truth[0]]],
                            )[0]
                        )
                    if "telemetry_lat" in geo_truth:
                        geo_truth["telemetry_error_m"] = float(
                            haversine_m(
                                [[as_json["centre_lon"], as_json["centre_lat"]]],
                                [[geo_truth["telemetry_lon"], geo_truth["telemetry_lat"]]],
                            )[0]
                        )
                outcome = FrameOutcome(
                    frame.index,
                    str(frame.frame_id),
                    status,
                    elapsed,
                    frame.true_tile_present,
                    result.per_candidate[0].inlier_count,
                    best_input,
                    best_input == frame.true_index,
                    mean_err,
                    result.reprojection_residual_px,
                    result_fingerprint(result),
                    None,
                    as_json,
                    **geo_truth,
                )
            else:
                outcome = FrameOutcome(
                    frame.index,
                    str(frame.frame_id),
                    status,
                    elapsed,
                    frame.true_tile_present,
                    0,
                    None,
                    False,
                    math.nan,
                    math.nan,
                    result_fingerprint(None, best_count) if status == "insufficient" else "",
                    error,
                    None,
                    insufficient_best=best_count,
                    **geo_truth,
                )
            outcomes.append(outcome)
            if progress is not None:
                progress(n, len(todo))
    return outcomes


@contextmanager
def build_matcher(
    settings: C3Settings, strategy: str, out_dir: Path, log_level: str | None = None
) -> Iterator[CrossDomainMatcher]:
    """A matcher for ``strategy`` (a linked strategy through ``compose_root``, or
    the ``sift_magsac`` baseline, also a strategy) whose FDR records go to
    ``out_dir/fdr.jsonl`` and JSON logs to ``out_dir/matcher.log``."""
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher.logs import configure_logging

    out_dir.mkdir(parents=True, exist_ok=True)
    for name in ("fdr.jsonl", "matcher.log"):
        (out_dir / name).unlink(missing_ok=True)
    clock = MonotonicClock()
    fdr = JsonlFdrRecorder(out_dir / "fdr.jsonl", clock, max_bytes=settings.fdr.max_bytes)
    log_stream = (out_dir / "matcher.log").open("w", encoding="utf-8")
    logs = configure_logging(fdr, level=log_level or settings.logging.level, stream=log_stream)
    root = None
    try:
        chosen = settings.model_copy(
            update={"matcher": settings.matcher.model_copy(update={"strategy": strategy})}
        )
        helpers = build_default_helpers(chosen)
        root = compose_root(
            chosen, {**helpers, "c13_fdr": fdr, "clock": clock}, configure_logs=False
        )
        matcher = root.matcher
        yield matcher
    finally:
        if root is not None:
            root.close()
        logs.close()
        fdr.close()
        log_stream.close()


def _percentile(values: list[float], q: float) -> float | None:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.percentile(np.asarray(finite), q)) if finite else None


def summarize(outcomes: list[FrameOutcome]) -> dict[str, Any]:
    """Counts and timing (ms) of a run; position errors (m) against ground truth and, for a
    recorded flight, the estimate minus the telemetry's position (its stated GNSS accuracy
    beside it, and the frames whose GNSS was absent or degraded)."""
    times = [o.elapsed_ms for o in outcomes]
    present = [o for o in outcomes if o.true_present]
    pos = [o.position_error_m for o in outcomes if o.status == "ok"]
    tele = [o for o in outcomes if o.telemetry_lat is not None]
    tele_err = [o.telemetry_error_m for o in tele if o.status == "ok"]
    accuracy = [o.gnss_accuracy_m for o in tele if o.gnss_accuracy_m is not None]
    return {
        "frames": len(outcomes),
        "ok": sum(o.status == "ok" for o in outcomes),
        "insufficient": sum(o.status == "insufficient" for o in outcomes),
        "backbone_error": sum(o.status == "backbone_error" for o in outcomes),
        "with_truth": sum(o.has_truth for o in outcomes),
        "true_present": len(present),
        "correct_candidate": sum(o.correct for o in present),
        "georeferenced": sum(o.est_lat is not None for o in outcomes),
        "position_error_m_p50": _percentile(pos, 50),
        "position_error_m_p95": _percentile(pos, 95),
        "with_telemetry": len(tele),
        "telemetry_error_m_p50": _percentile(tele_err, 50),
        "telemetry_error_m_p95": _percentile(tele_err, 95),
        "telemetry_error_m_p50_gnss_good": _percentile(
            [o.telemetry_error_m for o in tele if o.status == "ok" and not o.gnss_degraded], 50
        ),
        "gnss_accuracy_m_p50": _percentile(accuracy, 50),
        "gnss_degraded_frames": [o.index for o in tele if o.gnss_degraded],
        "frame_ms_p50": _percentile(times, 50),
        "frame_ms_p95": _percentile(times, 95),
        "frame_ms_mean": float(np.mean(times)) if times else None,
        "total_s": float(np.sum(times)) / 1e3,
    }


def register_replay_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "replay",
        help="run every frame of a flight dataset through the matcher (results, FDR, report)",
        description="Replay a c3-flight/1 dataset (see c3_matcher_tools.dataset.format) "
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
        help="output directory (default out/replay/<dataset>-<strategy>)",
    )
    p.add_argument(
        "--limit", type=positive_int("--limit"), default=None, help="only the first N frames (>= 1)"
    )
    p.add_argument(
        "--max-keypoints",
        type=positive_int("--max-keypoints", low=16, high=8192),
        default=None,
        help="override [matcher] max_keypoints (16..8192)",
    )
    p.add_argument(
        "--no-correspondences",
        action="store_true",
        help="omit inlier correspondences from results.jsonl",
    )
    add_attitude_noise_option(p)
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(handler=run_replay)


def add_attitude_noise_option(p: argparse.ArgumentParser) -> None:
    """``--attitude-noise-deg``: replay the flight as an IMU with that much error reports it."""
    p.add_argument(
        "--attitude-noise-deg",
        type=non_negative_float("--attitude-noise-deg"),
        default=0.0,
        help="add seeded Gaussian noise of this sigma (deg) to every frame's roll, pitch and yaw "
        "(an IMU's error; the same per frame in every run; default 0)",
    )


def non_negative_float(what: str) -> Callable[[str], float]:
    """An argparse type: a finite float >= 0, else a usage error (exit 2) naming ``what``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}: expected a number, got {text!r}") from None
        if not math.isfinite(value) or value < 0:
            raise argparse.ArgumentTypeError(f"{what}: must be finite and >= 0, got {value}")
        return value

    return parse


def positive_int(what: str, low: int = 1, high: int | None = None) -> Callable[[str], int]:
    """An argparse type: an int in [low, high], else a usage error (exit 2) naming ``what``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}: expected an integer, got {text!r}") from None
        if value < low or (high is not None and value > high):
            bound = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise argparse.ArgumentTypeError(f"{what}: must be {bound}, got {value}")
        return value

    return parse


def check_calibration_size(dataset: FlightDataset, frame: FrameRecord) -> None:
    """A calibration made for another image size is bad input (exit 2) naming both sizes,
    not a backbone failure on every frame."""
    h, w = dataset.nav_frame(frame).image.shape[:2]
    cw, ch = dataset.calibration.image_size
    if (cw, ch) != (w, h):
        raise InvalidInputError(
            str(dataset.root / str(dataset.meta["calibration"])),
            f"image_size is {cw}x{ch} px but frame {frame.image} is {w}x{h} px",
        )


def with_overrides(settings: C3Settings, max_keypoints: int | None) -> C3Settings:
    if max_keypoints is None:
        return settings
    return settings.model_copy(
        update={"matcher": settings.matcher.model_copy(update={"max_keypoints": max_keypoints})}
    )


def run_replay(args: argparse.Namespace, settings: C3Settings) -> int:
    dataset = with_attitude_noise(load_dataset(args.dataset), args.attitude_noise_deg)
    settings = with_overrides(settings, args.max_keypoints)
    strategy = args.strategy or settings.matcher.strategy
    out = args.out or Path("out") / "replay" / f"{dataset.name}-{strategy}"
    frames = list(dataset.frames[: args.limit] if args.limit else dataset.frames)
    if frames:
        check_calibration_size(dataset, frames[0])
    started = time.perf_counter()
    with build_matcher(settings, strategy, out) as matcher:
        startup_s = time.perf_counter() - started
        outcomes = run_flight(
            matcher,
            dataset,
            frames=frames,
            progress=ProgressBar(f"replay {dataset.name} {strategy}"),
            with_correspondences=not args.no_correspondences,
        )
    wall_s = time.perf_counter() - started
    with (out / "results.jsonl").open("w", encoding="utf-8") as fh:
        for o in outcomes:
            fh.write(json.dumps(o.to_json()) + "\n")
    labels = sorted({str(o.result["matcher_label"]) for o in outcomes if o.result})
    replayed = settings.matcher.model_copy(update={"strategy": strategy})
    report = {
        "dataset": str(dataset.root),
        "strategy": strategy,
        "matcher_labels": labels,
        "attitude_noise": dataset.meta.get("attitude_noise"),
        "settings": replayed.model_dump(mode="json"),
        "startup_s": startup_s,
        "wall_s": wall_s,
        **summarize(outcomes),
        "results": str(out / "results.jsonl"),
        "fdr": str(out / "fdr.jsonl"),
        "log": str(out / "matcher.log"),
    }
    write_flight_outputs(out, dataset, outcomes, strategy, report)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(
        f"replay {dataset.name} with {strategy}: {report['frames']} frames in {wall_s:.1f} s "
        f"(startup {startup_s:.1f} s)"
    )
    print(
        f"  ok {report['ok']}, insufficient inliers {report['insufficient']}, "
        f"backbone errors {report['backbone_error']}"
    )
    if report["with_truth"]:
        print(
            f"  correct candidate {report['correct_candidate']}/{report['true_present']} "
            "frames with the true tile present"
        )
    else:
        print("  no ground truth in this flight: nothing scored against truth")
    print(f"  frame ms p50 {report['frame_ms_p50']:.0f}, p95 {report['frame_ms_p95']:.0f}")
    if report["georeferenced"] and report["with_truth"]:
        print(
            f"  position error m p50 {_fmt(report['position_error_m_p50'])}, "
            f"p95 {_fmt(report['position_error_m_p95'])} ({report['georeferenced']} frames located)"
        )
    if report["with_telemetry"]:
        degraded = report["gnss_degraded_frames"]
        accuracy = report["gnss_accuracy_m_p50"]
        print(
            f"  estimate - telemetry position m p50 {_fmt(report['telemetry_error_m_p50'])}, "
            f"p95 {_fmt(report['telemetry_error_m_p95'])} ({report['georeferenced']} frames "
            "located; "
            + (
                "GNSS accuracy not stated"
                if accuracy is None
                else f"GNSS accuracy {accuracy:.1f} m"
            )
            + f"; GNSS absent or degraded on {len(degraded)} frame(s)"
            + (f": {degraded[:20]})" if degraded else ")")
        )
    print(f"  results {report['results']}, FDR {report['fdr']}, report {out / 'report.json'}")
    print(f"  map {report['geojson']}, flight report {report['html'] or '(not written)'}")
    return 0


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1f}"


def write_flight_outputs(
    out: Path,
    dataset: FlightDataset,
    outcomes: list[FrameOutcome],
    strategy: str,
    report: dict[str, Any],
) -> None:
    """``out/flight.geojson`` and ``out/report.html`` of one run (replay, and eval per
    strategy); their paths go into ``report["geojson"]`` / ``report["html"]`` (None: no
    matplotlib). ``report`` needs ``settings`` and :func:`summarize`'s keys."""
    from c3_matcher_tools.geojson import write_geojson

    report["geojson"] = str(write_geojson(out / "flight.geojson", outcomes, strategy))
    report["html"] = write_html_report(out, dataset, outcomes, strategy, report)


def write_html_report(
    out: Path,
    dataset: FlightDataset,
    outcomes: list[FrameOutcome],
    strategy: str,
    report: dict[str, Any],
) -> str | None:
    """``out/report.html`` (None, with the reason on stderr, when matplotlib is missing)."""
    import sys

    try:
        from c3_matcher_tools.report import write_report
    except ImportError as exc:
        print(f"c3-matcher: no report.html ({exc})", file=sys.stderr)
        return None
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print(
            "c3-matcher: no report.html: install the report extra "
            "(pip install 'c3-matcher-tools[report]')",
            file=sys.stderr,
        )
        return None
    from importlib.metadata import version

    summary = {k: v for k, v in report.items() if k not in ("settings",)}
    provenance = {
        "dataset": str(dataset.root),
        "dataset format": dataset.meta.get("format"),
        "tile store": str(dataset.store_path),
        "matcher labels (from the results)": ", ".join(report.get("matcher_labels", [])),
        "c3-matcher": version("c3-matcher"),
        "made by": json.dumps(dataset.meta.get("spec", dataset.meta.get("import", {}))),
    }
    path = write_report(
        out / "report.html",
        dataset,
        outcomes,
        strategy=strategy,
        summary=summary,
        settings=report["settings"],
        provenance=provenance,
    )
    return str(path)
