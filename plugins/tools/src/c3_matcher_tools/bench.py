"""``c3-matcher bench`` (C3-PT-01): per-frame and per-candidate latency (p50/p95, per stage) and
peak memory of each strategy on a demo-format frame with 3 candidates, beside, in the same run:

- the strategy's PyTorch reference (the upstream models through kornia, LightGlue with its
  adaptive depth and width ON, tiles re-extracted every frame), when the engine-build
  environment is installed and the strategy's plugin offers one (``c3_matcher_reference_backend``);
- the classical OpenCV SIFT + MAGSAC pipeline doing the same work;

as ratios. Engine runs are timed twice: with every tile new (decoded and extracted every frame)
and with the tiles cached (the steady state of a flight whose candidates were seen before).
``--sweep`` adds image-size x keypoint-budget variants. Every case runs in a fresh worker
process (``python -m c3_matcher_tools.bench``) so that its peak memory (``ru_maxrss``) is its own.
Wall-clock figures on a shared machine are noisy: compare ratios within one run.
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
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from c3_matcher.commands import CommandRegistry
from c3_matcher.config import C3Settings, load_settings

__all__ = ["BenchCase", "register_bench_command", "run_worker"]

REPO = Path(__file__).resolve().parents[4]
STAGES = ("decode", "preprocess", "extract", "match", "ransac")
Kind = Literal["engine", "pytorch", "sift"]
SWEEP_LONG_SIDES = (512, 1024)
SWEEP_KEYPOINTS = (512, 1024, 2048)


@dataclass(frozen=True)
class BenchCase:
    """One timed configuration: a strategy, how it runs, its tile cache and image rules."""

    strategy: str
    kind: Kind
    tile_cache_size: int
    max_long_side: int
    max_keypoints: int | None

    @property
    def label(self) -> str:
        name = {
            "engine": self.strategy,
            "pytorch": f"{self.strategy}[pytorch]",
            "sift": "sift_magsac",
        }[self.kind]
        tiles = "cached" if self.tile_cache_size else "new"
        budget = f"{self.max_keypoints} kp" if self.max_keypoints else "default kp"
        return f"{name} ({tiles} tiles, {self.max_long_side}px, {budget})"


def _inputs(data_dir: Path) -> list[tuple[Any, Any, Any]]:
    """(frame, rerank, calibration) per frame: a flight dataset's frames whose true tile is
    present (``dataset.json``), or the single frame of a demo-format directory."""
    if (data_dir / "dataset.json").is_file():
        from c3_matcher_tools.dataset.format import load_dataset

        dataset = load_dataset(data_dir)
        store = dataset.open_store()
        return [
            (dataset.nav_frame(f), dataset.rerank(f, store), dataset.calibration)
            for f in dataset.frames
            if f.true_tile_present
        ]
    return [_demo_inputs(data_dir)]


def _demo_inputs(data_dir: Path) -> tuple[Any, Any, Any]:
    from c3_matcher.dto import Attitude, NavCameraFrame, RerankCandidate, RerankResult, TileId
    from c3_matcher.serialize import load_calibration
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
    calibration = load_calibration(data_dir / "calibration.json")
    return frame, RerankResult(frame.frame_id, candidates), calibration


def _percentiles(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def _matcher(case: BenchCase, settings: C3Settings, fdr: Any, clock: Any) -> tuple[Any, str]:
    from c3_matcher.compose import build_default_helpers, build_plugin_host, compose_root
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
    from c3_matcher.ransac import OpenCvRansacFilter
    from c3_matcher_tools.baselines import SIFT_LABEL

    m = settings.matcher
    if case.kind == "pytorch":
        backend = build_plugin_host().reference_backend(case.strategy, settings)
        if backend is None:
            raise SystemExit(f"no PyTorch reference for {case.strategy}")
        pipeline = PipelineMatcher(
            backend,
            OpenCvRansacFilter(seed=m.ransac_seed),
            fdr,
            RollingHealthWindow(clock, m.min_inliers_threshold),
            clock,
            PipelineSettings.from_settings(m),
        )
        return pipeline, str(backend.provenance()["provider"])
    strategy = SIFT_LABEL if case.kind == "sift" else case.strategy
    chosen = settings.model_copy(update={"matcher": m.model_copy(update={"strategy": strategy})})
    helpers = build_default_helpers(chosen)
    root = compose_root(chosen, {**helpers, "c13_fdr": fdr, "clock": clock}, configure_logs=False)
    provider = "opencv" if case.kind == "sift" else helpers["c7_inference"].provider
    return root.matcher, provider


def run_worker(case: BenchCase, runs: int, data_dir: Path, settings: C3Settings) -> dict[str, Any]:
    """Time ``runs`` matches of the demo frame (after 2 warm-up runs) in this process."""
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock

    settings = settings.model_copy(
        update={
            "matcher": settings.matcher.model_copy(
                update={
                    "strategy": case.strategy,
                    "tile_cache_size": case.tile_cache_size,
                    "max_long_side": case.max_long_side,
                    "max_keypoints": case.max_keypoints,
                }
            )
        }
    )
    inputs = _inputs(data_dir)
    clock = MonotonicClock()
    fdr = JsonlFdrRecorder(Path(tempfile.mkdtemp(prefix="c3-bench-")) / "fdr.jsonl", clock)
    started = time.perf_counter()
    matcher, provider = _matcher(case, settings, fdr, clock)
    startup_s = time.perf_counter() - started
    frame_ms: list[float] = []
    candidate_ms: list[float] = []
    stages: dict[str, list[float]] = {s: [] for s in ("query_preprocess", "query_extract", *STAGES)}
    from c3_matcher.errors import InsufficientInliersError

    best: list[int] = []
    for i in range(runs + 2):
        frame, rerank, calibration = inputs[i % len(inputs)]
        t0 = time.perf_counter()
        try:
            result = matcher.match(frame, rerank, calibration)
        except InsufficientInliersError:
            result = None
        elapsed = (time.perf_counter() - t0) * 1e3
        if i < 2:
            continue
        frame_ms.append(elapsed)
        if result is None:
            best.append(0)
            continue
        best.append(result.per_candidate[0].inlier_count)
        diag = result.diagnostics
        for key in ("query_preprocess", "query_extract"):
            stages[key].append(diag["timings_ms"][key])
        for cand in diag["per_candidate_timings_ms"]:
            candidate_ms.append(sum(cand.get(s, 0.0) for s in STAGES))
            for s in STAGES:
                stages[s].append(cand.get(s, 0.0))
    return {
        "case": asdict(case),
        "label": case.label,
        "provider": provider,
        "runs": runs,
        "startup_s": startup_s,
        "best_inliers": int(np.median(best)),
        "frame_ms": _percentiles(frame_ms),
        "per_candidate_ms": _percentiles(candidate_ms),
        "stages_ms": {k: _percentiles(v) for k, v in stages.items() if v},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _machine() -> dict[str, Any]:
    import onnxruntime as ort

    return {
        "platform": platform.platform(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "onnxruntime": ort.__version__,
        "available_providers": ort.get_available_providers(),
    }


def _has_torch() -> bool:
    import importlib.util

    return importlib.util.find_spec("torch") is not None


def cases_for(args: argparse.Namespace, settings: C3Settings) -> list[BenchCase]:
    m = settings.matcher
    cached = max(m.tile_cache_size, 3)
    cases: list[BenchCase] = []
    for name in args.strategy or [m.strategy]:
        cases += [
            BenchCase(name, "engine", 0, m.max_long_side, m.max_keypoints),
            BenchCase(name, "engine", cached, m.max_long_side, m.max_keypoints),
        ]
        if not args.no_reference and _has_torch():
            cases.append(BenchCase(name, "pytorch", 0, m.max_long_side, m.max_keypoints))
        if args.sweep:
            cases += [
                BenchCase(name, "engine", 0, side, kp)
                for side in SWEEP_LONG_SIDES
                for kp in SWEEP_KEYPOINTS
                if (side, kp) != (m.max_long_side, m.max_keypoints)
            ]
    if not args.no_baseline:
        cases.append(BenchCase(m.strategy, "sift", 0, m.max_long_side, m.max_keypoints))
    return cases


def register_bench_command(commands: CommandRegistry) -> None:
    p = commands.add(
        "bench",
        help="C3-PT-01: latency and peak memory beside the PyTorch "
        "reference and the SIFT + MAGSAC baseline",
    )
    p.add_argument("--runs", type=int, default=20, help="timed runs per case (default 20)")
    p.add_argument(
        "--strategy",
        action="append",
        default=None,
        help="strategy to bench (repeatable; default: the configured one)",
    )
    p.add_argument("--no-baseline", action="store_true", help="skip SIFT + MAGSAC")
    p.add_argument("--no-reference", action="store_true", help="skip the PyTorch reference")
    p.add_argument(
        "--sweep",
        action="store_true",
        help=f"also image long side {SWEEP_LONG_SIDES} x keypoints {SWEEP_KEYPOINTS}",
    )
    p.add_argument(
        "--data",
        type=Path,
        default=REPO / "data" / "demo",
        help="a flight dataset (c3-flight/1, its frames in turn) or a demo-format directory "
        "(default: the built-in demo frame)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.set_defaults(handler=run_bench)


def run_bench(args: argparse.Namespace, settings: C3Settings) -> int:
    results = []
    for case in cases_for(args, settings):
        print(f"bench: {case.label}, {args.runs} runs...", file=sys.stderr, flush=True)
        cmd = [
            sys.executable,
            "-m",
            "c3_matcher_tools.bench",
            json.dumps(asdict(case)),
            str(args.runs),
            str(args.data),
        ]
        if args.config:
            cmd += ["--config", str(args.config)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    report: dict[str, Any] = {"machine": _machine(), "runs": args.runs, "results": results}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(format_report(report))
    return 0


def format_report(report: dict[str, Any]) -> str:
    results = report["results"]
    sift = next((r for r in results if r["case"]["kind"] == "sift"), None)
    torch_ref = {r["case"]["strategy"]: r for r in results if r["case"]["kind"] == "pytorch"}
    m = report["machine"]
    lines = [
        f"machine: {m['platform']}, {m['cpus']} CPUs, onnxruntime {m['onnxruntime']} "
        f"(providers {', '.join(m['available_providers'])}); {report['runs']} runs per "
        "case; frame = 1 query + 3 candidate tiles",
        f"{'case':58} {'provider':22} {'frame p50':>9} {'frame p95':>9} {'cand p95':>8} "
        f"{'peak MB':>7} {'inliers':>7} {'vs torch':>8} {'vs SIFT':>7}",
    ]
    for r in results:
        ref = torch_ref.get(r["case"]["strategy"])
        vs_torch = (
            f"{r['frame_ms']['p95'] / ref['frame_ms']['p95']:.2f}x"
            if ref and r["case"]["kind"] == "engine"
            else ""
        )
        vs_sift = f"{r['frame_ms']['p95'] / sift['frame_ms']['p95']:.2f}x" if sift else ""
        lines.append(
            f"{r['label']:58} {r['provider'][:22]:22} {r['frame_ms']['p50']:9.0f} "
            f"{r['frame_ms']['p95']:9.0f} {r['per_candidate_ms']['p95']:8.0f} "
            f"{r['peak_rss_mb']:7.0f} {r['best_inliers']:7d} {vs_torch:>8} "
            f"{vs_sift:>7}"
        )
    lines.append("per stage, ms (p50/p95):")
    for r in results:
        parts = [f"{k} {v['p50']:.0f}/{v['p95']:.0f}" for k, v in r["stages_ms"].items()]
        lines.append(f"  {r['label']}: " + ", ".join(parts))
    return "\n".join(lines)


def _worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m c3_matcher_tools.bench")
    parser.add_argument("case", help="BenchCase as JSON")
    parser.add_argument("runs", type=int)
    parser.add_argument("data", type=Path)
    parser.add_argument("--config", type=Path, default=None)
    args = parser.parse_args(argv)
    from loguru import logger

    logger.remove()
    case = BenchCase(**json.loads(args.case))
    print(json.dumps(run_worker(case, args.runs, args.data, load_settings(args.config))))
    return 0


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1:]))
