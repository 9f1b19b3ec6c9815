"""``c3-matcher bench``: per-frame and per-candidate latency (p50/p95 per stage) and peak memory
of the matcher at the configured settings, on the built-in demo data (one frame, 3 candidates),
beside the classical OpenCV SIFT + MAGSAC pipeline doing the same work, in the same run.

Each configuration runs in a fresh worker process (``python -m c3_matcher.bench``) so that
its peak memory (``ru_maxrss``) is its own. Wall-clock figures on a shared machine are noisy:
compare ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings, load_settings

__all__ = ["add_bench_command", "run_worker"]

REPO = Path(__file__).resolve().parents[3]
STAGES = ("decode", "preprocess", "extract", "match", "ransac")


def _demo_inputs(data_dir: Path) -> tuple[Any, Any, Any]:
    from c3_matcher.dto import Attitude, NavCameraFrame, RerankCandidate, RerankResult, TileId
    from c3_matcher.match_cli import load_calibration
    from c3_matcher.tiles import MmapTileHandle, read_image

    meta = json.loads((data_dir / "demo.json").read_text())
    att = meta["attitude_deg"]
    frame = NavCameraFrame(
        uuid.UUID(int=1),
        read_image(data_dir / "frame.jpg"),
        1,
        Attitude.from_degrees(att["roll"], att["pitch"], att["yaw"]),
        meta["height_m"],
    )
    candidates = tuple(
        RerankCandidate(
            TileId(*t["tile_id"]), 1.0, MmapTileHandle(data_dir / t["file"]), meta["tile_gsd_m"]
        )
        for t in meta["tiles"]
    )
    return (
        frame,
        RerankResult(frame.frame_id, candidates),
        load_calibration(data_dir / "calibration.json"),
    )


def _percentiles(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def run_worker(
    strategy: str, runs: int, data_dir: Path, settings: C3Settings, tile_cache_size: int
) -> dict[str, Any]:
    """Time ``runs`` matches of the demo frame (after 2 warm-up runs) in this process.

    ``tile_cache_size`` 0 re-extracts every tile every frame (all candidates new); > 0 is the
    steady state of a flight where the candidates were seen in earlier frames."""
    from c3_matcher.baselines import SIFT_LABEL, SiftBackend
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock, RollingHealthWindow
    from c3_matcher.pipeline import MatchPipeline, PipelineSettings
    from c3_matcher.preprocess import InputRule
    from c3_matcher.ransac import OpenCvRansacFilter

    frame, rerank, calibration = _demo_inputs(data_dir)
    tmp = Path(tempfile.mkdtemp(prefix="c3-bench-"))
    clock = MonotonicClock()
    fdr = JsonlFdrRecorder(tmp / "fdr.jsonl", clock)
    started = time.perf_counter()
    provider = "opencv"
    if strategy == SIFT_LABEL:
        m = settings.matcher
        matcher: Any = MatchPipeline(
            SiftBackend(InputRule(m.max_long_side, 16), m.max_keypoints),
            OpenCvRansacFilter(seed=m.ransac_seed),
            fdr,
            RollingHealthWindow(clock, m.min_inliers_threshold),
            clock,
            PipelineSettings(
                m.min_inliers_threshold, m.residual_warn_threshold_px, m.ransac_threshold_px
            ),
        )
    else:
        settings = settings.model_copy(
            update={
                "matcher": settings.matcher.model_copy(
                    update={"strategy": strategy, "tile_cache_size": tile_cache_size}
                )
            }
        )
        helpers = build_default_helpers(settings)
        provider = helpers["c7_inference"].provider
        matcher = compose_root(settings, {**helpers, "c13_fdr": fdr}, configure_logs=False).matcher
    startup_s = time.perf_counter() - started
    frame_ms: list[float] = []
    per_candidate_ms: list[float] = []
    stages: dict[str, list[float]] = {s: [] for s in ("query_preprocess", "query_extract", *STAGES)}
    inliers = 0
    for i in range(runs + 2):
        t0 = time.perf_counter()
        result = matcher.match(frame, rerank, calibration)
        elapsed = (time.perf_counter() - t0) * 1e3
        if i < 2:
            continue
        frame_ms.append(elapsed)
        inliers = result.per_candidate[0].inlier_count
        diag = result.diagnostics
        for key in ("query_preprocess", "query_extract"):
            stages[key].append(diag["timings_ms"][key])
        for cand in diag["per_candidate_timings_ms"]:
            per_candidate_ms.append(sum(cand.get(s, 0.0) for s in STAGES))
            for s in STAGES:
                stages[s].append(cand.get(s, 0.0))
    return {
        "strategy": strategy,
        "tiles": "cached" if tile_cache_size and strategy != SIFT_LABEL else "new",
        "provider": provider,
        "runs": runs,
        "startup_s": startup_s,
        "best_inliers": inliers,
        "frame_ms": _percentiles(frame_ms),
        "per_candidate_ms": _percentiles(per_candidate_ms),
        "stages_ms": {k: _percentiles(v) for k, v in stages.items() if v},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _machine() -> dict[str, Any]:
    import onnxruntime as ort

    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "onnxruntime": ort.__version__,
        "available_providers": ort.get_available_providers(),
    }


def add_bench_command(sub: Any) -> Any:
    p = sub.add_parser(
        "bench",
        help="latency (per frame, per candidate, per stage) and peak "
        "memory beside the SIFT + MAGSAC baseline",
    )
    p.add_argument("--runs", type=int, default=20, help="timed runs per strategy (default 20)")
    p.add_argument(
        "--strategy",
        action="append",
        default=None,
        help="strategy to bench (repeatable; default: the configured one)",
    )
    p.add_argument("--no-baseline", action="store_true", help="skip the SIFT baseline")
    p.add_argument(
        "--data",
        type=Path,
        default=REPO / "data" / "demo",
        help="demo-format data directory (default: the built-in demo)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    return run_bench


def run_bench(args: argparse.Namespace, settings: C3Settings) -> int:
    from c3_matcher.baselines import SIFT_LABEL

    cases = [
        (name, cache)
        for name in (args.strategy or [settings.matcher.strategy])
        for cache in (0, max(settings.matcher.tile_cache_size, 3))
    ]
    if not args.no_baseline:
        cases.append((SIFT_LABEL, 0))
    results = []
    for name, cache in cases:
        print(
            f"bench: {name}, tile cache {cache} ({args.runs} runs)...", file=sys.stderr, flush=True
        )
        cmd = [
            sys.executable,
            "-m",
            "c3_matcher.bench",
            name,
            str(args.runs),
            str(args.data),
            "--tile-cache",
            str(cache),
        ]
        if args.config:
            cmd += ["--config", str(args.config)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    report: dict[str, Any] = {
        "machine": _machine(),
        "settings": settings.matcher.model_dump(mode="json"),
        "results": results,
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    base = next((r for r in results if r["strategy"] == SIFT_LABEL), None)
    results.sort(key=lambda r: (r["strategy"] == SIFT_LABEL, r["tiles"] != "new"))
    m = report["machine"]
    print(f"machine: {m['platform']}, {m['cpus']} CPUs, onnxruntime {m['onnxruntime']}")
    print(
        f"settings: long side {settings.matcher.max_long_side}, "
        f"{settings.matcher.max_keypoints} keypoints, 3 candidates, {args.runs} runs"
    )
    print(
        "tiles: 'new' = every candidate decoded and extracted (first sight); 'cached' = "
        "candidates seen in earlier frames (tile feature cache)"
    )
    header = (
        f"{'strategy':16} {'tiles':7} {'provider':22} {'frame p50':>10} {'frame p95':>10} "
        f"{'cand p95':>9} {'peak MB':>8} {'inliers':>8}" + ("  p95 vs SIFT" if base else "")
    )
    print(header)
    for r in results:
        ratio = f"  {r['frame_ms']['p95'] / base['frame_ms']['p95']:.2f}x" if base else ""
        print(
            f"{r['strategy']:16} {r['tiles']:7} {r['provider']:22} {r['frame_ms']['p50']:10.1f} "
            f"{r['frame_ms']['p95']:10.1f} {r['per_candidate_ms']['p95']:9.1f} "
            f"{r['peak_rss_mb']:8.0f} {r['best_inliers']:8d}{ratio}"
        )
    print("per stage, ms (p50 / p95):")
    for r in results:
        parts = [f"{k} {v['p50']:.1f}/{v['p95']:.1f}" for k, v in r["stages_ms"].items()]
        print(f"  {r['strategy']} ({r['tiles']} tiles): " + ", ".join(parts))
    return 0


def _worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m c3_matcher.bench")
    parser.add_argument("strategy")
    parser.add_argument("runs", type=int)
    parser.add_argument("data", type=Path)
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--tile-cache", type=int, default=0)
    args = parser.parse_args(argv)
    from loguru import logger

    logger.remove()
    print(
        json.dumps(
            run_worker(
                args.strategy, args.runs, args.data, load_settings(args.config), args.tile_cache
            )
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1:]))
