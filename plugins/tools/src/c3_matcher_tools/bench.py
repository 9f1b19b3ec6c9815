"""``c3-matcher bench`` (C3-PT-01): per-frame and per-candidate latency (p50/p95, per stage) and
peak memory of each strategy on a demo-format frame with 3 candidates, beside, in the same run:

- the strategy's PyTorch reference (the upstream models through kornia, LightGlue with its
  adaptive depth and width ON, tiles re-extracted every frame), when the engine-build
  environment is installed and the strategy's plugin offers one (``c3_matcher_reference_backend``);
- the classical OpenCV SIFT + MAGSAC pipeline doing the same work;

as ratios. Engine runs are timed with every tile new (decoded and extracted every frame) and
with the tiles cached (the steady state of a flight whose candidates were seen before); in the
same run, when they apply:

- stored map features (``[matcher] stored_features`` on, tiles never extracted in flight) vs
  extraction, when ``--data`` is a flight whose store has features built
  (``c3-matcher features build``); the FDR-style source of every candidate's features is
  counted so a case that silently fell back to extraction shows it;
- full vs adaptive LightGlue (``[lightglue] mode``) for the LightGlue-family strategies.

Ratios are speed-ups of frame p50 (slower / faster, >1 means the case is faster).
``--sweep`` adds image-size x keypoint-budget variants; ``--max-keypoints N`` and ``--threads N``
(repeatable) add keypoint-budget and ONNX Runtime intra-op thread variants (new tiles). Every
case runs in a fresh worker process (``python -m c3_matcher_tools.bench``) so that its peak
memory (``ru_maxrss``) is its own.
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
    stored_features: bool = False
    lightglue_mode: str | None = None  # None: as configured
    intra_op_threads: int | None = None  # None: as configured

    @property
    def label(self) -> str:
        name = {
            "engine": self.strategy,
            "pytorch": f"{self.strategy}[pytorch]",
            "sift": "sift_magsac",
        }[self.kind]
        tiles = "cached" if self.tile_cache_size else "new"
        tiles = "stored" if self.stored_features else tiles
        budget = f"{self.max_keypoints} kp" if self.max_keypoints else "default kp"
        extra = f", LG {self.lightglue_mode}" if self.lightglue_mode else ""
        extra += f", {self.intra_op_threads} thr" if self.intra_op_threads else ""
        return f"{name} ({tiles} tiles, {self.max_long_side}px, {budget}{extra})"


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


def stored_features_path(data_dir: Path) -> Path | None:
    """The features sidecar of a flight dataset's store (``<store>.features.sqlite``), if any."""
    meta = data_dir / "dataset.json"
    if not meta.is_file():
        return None
    store = data_dir / str(json.loads(meta.read_text()).get("store", "tiles.mbtiles"))
    sidecar = store.with_name(store.name + ".features.sqlite")
    return sidecar if sidecar.is_file() else None


def _uses_lightglue(strategy: str) -> bool:
    return "glue" in strategy


def _percentiles(values: list[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def _matcher(case: BenchCase, settings: C3Settings, fdr: Any, clock: Any) -> tuple[Any, str]:
    from c3_matcher.compose import (
        build_default_helpers,
        build_plugin_host,
        compose_root,
        strategy_settings,
    )
    from c3_matcher.health import RollingHealthWindow
    from c3_matcher.pipeline import PipelineMatcher, PipelineSettings
    from c3_matcher.ransac import OpenCvRansacFilter
    from c3_matcher_tools.baselines import SIFT_LABEL

    if case.kind == "pytorch":
        host = build_plugin_host()
        settings = strategy_settings(settings, case.strategy, host)  # the strategy's defaults
        m = settings.matcher
        backend = host.reference_backend(case.strategy, settings)
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
    m = settings.matcher
    chosen = settings.model_copy(update={"matcher": m.model_copy(update={"strategy": strategy})})
    helpers = build_default_helpers(chosen)
    root = compose_root(chosen, {**helpers, "c13_fdr": fdr, "clock": clock}, configure_logs=False)
    provider = "opencv" if case.kind == "sift" else helpers["c7_inference"].provider
    return root.matcher, provider


def run_worker(case: BenchCase, runs: int, data_dir: Path, settings: C3Settings) -> dict[str, Any]:
    """Time ``runs`` matches of the demo frame (after 2 warm-up runs) in this process."""
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock

    matcher_update: dict[str, Any] = {
        "strategy": case.strategy,
        "tile_cache_size": case.tile_cache_size,
        "max_long_side": case.max_long_side,
        "max_keypoints": case.max_keypoints,
    }
    if "stored_features" in type(settings.matcher).model_fields:
        matcher_update["stored_features"] = case.stored_features
    update: dict[str, Any] = {"matcher": settings.matcher.model_copy(update=matcher_update)}
    lightglue = getattr(settings, "lightglue", None)
    if case.lightglue_mode and lightglue is not None:
        update["lightglue"] = lightglue.model_copy(update={"mode": case.lightglue_mode})
    if case.intra_op_threads:
        update["engines"] = settings.engines.model_copy(
            update={"intra_op_threads": case.intra_op_threads}
        )
    settings = settings.model_copy(update=update)
    inputs = _inputs(data_dir)
    clock = MonotonicClock()
    fdr = JsonlFdrRecorder(Path(tempfile.mkdtemp(prefix="c3-bench-")) / "fdr.jsonl", clock)
    started = time.perf_counter()
    matcher, provider = _matcher(case, settings, fdr, clock)
    if hasattr(matcher, "stored_features"):  # the setting, applied whatever the composition did
        matcher.stored_features = case.stored_features
    startup_s = time.perf_counter() - started
    frame_ms: list[float] = []
    candidate_ms: list[float] = []
    stages: dict[str, list[float]] = {s: [] for s in ("query_preprocess", "query_extract", *STAGES)}
    from c3_matcher.errors import InsufficientInliersError

    best: list[int] = []
    sources: dict[str, int] = {}
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
        for source in diag.get("candidate_features", ()):
            sources[source] = sources.get(source, 0) + 1
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
        "feature_sources": sources,
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
    stored = stored_features_path(args.data) is not None
    lightglue = getattr(settings, "lightglue", None)
    other_mode = None
    if lightglue is not None:  # the mode the configured provider runs, then the other one
        import onnxruntime as ort

        from c3_matcher.engines.lightglue import resolve_mode
        from c3_matcher.engines.runtime import resolve_providers

        provider = resolve_providers(settings.engines.providers, ort.get_available_providers())
        mode = resolve_mode(lightglue.mode, provider[0])
        other_mode = {"adaptive": "full", "full": "adaptive"}[mode]
    cases: list[BenchCase] = []
    for name in args.strategy or [m.strategy]:
        cases += [
            BenchCase(name, "engine", 0, m.max_long_side, m.max_keypoints),
            BenchCase(name, "engine", cached, m.max_long_side, m.max_keypoints),
        ]
        if stored and not getattr(args, "no_stored", False):
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, m.max_keypoints, True))
        if other_mode and _uses_lightglue(name) and not getattr(args, "no_modes", False):
            cases.append(
                BenchCase(name, "engine", 0, m.max_long_side, m.max_keypoints, False, other_mode)
            )
        for kp in getattr(args, "keypoints", None) or ():
            cases.append(BenchCase(name, "engine", 0, m.max_long_side, kp))
        for threads in getattr(args, "threads", None) or ():
            cases.append(
                BenchCase(name, "engine", 0, m.max_long_side, m.max_keypoints, False, None, threads)
            )
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
    p.add_argument(
        "--no-stored",
        action="store_true",
        help="skip the stored-features case (added when --data's store has features built)",
    )
    p.add_argument(
        "--no-modes",
        action="store_true",
        help="skip the other [lightglue] mode (full vs adaptive) for LightGlue strategies",
    )
    p.add_argument(
        "--max-keypoints",
        dest="keypoints",
        type=int,
        action="append",
        default=None,
        help="also time a keypoint budget of N per image, new tiles (repeatable)",
    )
    p.add_argument(  # the former name, still accepted
        "--keypoints", dest="keypoints", type=int, action="append", help=argparse.SUPPRESS
    )
    p.add_argument(
        "--threads",
        type=int,
        action="append",
        default=None,
        help="also time ONNX Runtime intra-op threads N, new tiles (repeatable)",
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
        out = subprocess.run(cmd, check=False, capture_output=True, text=True)
        if out.returncode != 0:
            raise SystemExit(f"bench: {case.label} failed:\n{out.stderr.strip()}")
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    report: dict[str, Any] = {
        "machine": _machine(),
        "runs": args.runs,
        "data": str(args.data),
        "results": results,
        "comparisons": comparisons(results),
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(format_report(report))
    return 0


def _speedup(slow: dict[str, Any] | None, fast: dict[str, Any] | None, key: str = "p50") -> str:
    """``slow / fast`` of frame ``key`` as ``"2.50x"`` (>1: ``fast`` is faster); '' if absent."""
    if not slow or not fast or not fast["frame_ms"][key]:
        return ""
    return f"{slow['frame_ms'][key] / fast['frame_ms'][key]:.2f}x"


def _sources(r: dict[str, Any]) -> str:
    counts = r.get("feature_sources") or {}
    total = sum(counts.values())
    if not total:
        return ""
    return " ".join(f"{k} {v}/{total}" for k, v in sorted(counts.items()) if k != "none") or ""


def comparisons(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The ratios a run proves, per strategy: stored vs extracted tiles, adaptive vs full
    LightGlue, cached vs new tiles, each engine case vs the PyTorch reference (speed-ups of
    frame p50 and p95, peak RSS of both sides)."""

    def find(strategy: str, kind: str, **fields: Any) -> dict[str, Any] | None:
        for r in results:
            c = r["case"]
            same = c["strategy"] == strategy and c["kind"] == kind
            if same and all(c.get(k) == v for k, v in fields.items()):
                return r
        return None

    out: list[dict[str, Any]] = []
    for strategy in dict.fromkeys(r["case"]["strategy"] for r in results):
        base = dict(stored_features=False, lightglue_mode=None, intra_op_threads=None)
        new = find(strategy, "engine", tile_cache_size=0, **base)
        cached = next(
            (
                r
                for r in results
                if r["case"]["strategy"] == strategy
                and r["case"]["kind"] == "engine"
                and r["case"]["tile_cache_size"] > 0
            ),
            None,
        )
        stored = find(strategy, "engine", stored_features=True)
        other = next(
            (
                r
                for r in results
                if r["case"]["strategy"] == strategy
                and r["case"]["kind"] == "engine"
                and r["case"].get("lightglue_mode")
            ),
            None,
        )
        torch_ref = find(strategy, "pytorch")
        pairs: list[tuple[str, dict[str, Any] | None, dict[str, Any] | None]] = [
            ("cached vs new tiles", new, cached),
            ("stored features vs extraction", new, stored),
        ]
        if other is not None:
            mode = other["case"]["lightglue_mode"]
            if mode == "full":
                pairs.append(("adaptive vs full LightGlue", other, new))
            else:
                pairs.append(("adaptive vs full LightGlue", new, other))
        for r in (new, cached, stored, other):
            if r is not None:
                pairs.append((f"{r['label']} vs PyTorch", torch_ref, r))
        for what, slow, fast in pairs:
            if slow is None or fast is None:
                continue
            out.append(
                {
                    "strategy": strategy,
                    "comparison": what,
                    "speedup_p50": slow["frame_ms"]["p50"] / fast["frame_ms"]["p50"],
                    "speedup_p95": slow["frame_ms"]["p95"] / fast["frame_ms"]["p95"],
                    "peak_rss_mb": (fast["peak_rss_mb"], slow["peak_rss_mb"]),
                }
            )
    return out


def format_report(report: dict[str, Any]) -> str:
    results = report["results"]
    sift = next((r for r in results if r["case"]["kind"] == "sift"), None)
    torch_ref = {r["case"]["strategy"]: r for r in results if r["case"]["kind"] == "pytorch"}
    m = report["machine"]
    lines = [
        f"machine: {m['platform']}, {m['cpus']} CPUs, onnxruntime {m['onnxruntime']} "
        f"(providers {', '.join(m['available_providers'])}); {report['runs']} runs per "
        f"case; data {report.get('data', '?')}; frame = 1 query + its candidate tiles",
        f"{'case':66} {'provider':18} {'frame p50':>9} {'frame p95':>9} {'cand p95':>8} "
        f"{'peak MB':>7} {'inliers':>7} {'vs torch':>8} {'vs SIFT':>7}  tile features",
    ]
    for r in results:
        ref = torch_ref.get(r["case"]["strategy"])
        vs_torch = _speedup(ref, r) if r["case"]["kind"] == "engine" else ""
        vs_sift = _speedup(sift, r) if sift and r is not sift else ""
        lines.append(
            f"{r['label']:66} {r['provider'][:18]:18} {r['frame_ms']['p50']:9.0f} "
            f"{r['frame_ms']['p95']:9.0f} {r['per_candidate_ms']['p95']:8.0f} "
            f"{r['peak_rss_mb']:7.0f} {r['best_inliers']:7d} {vs_torch:>8} "
            f"{vs_sift:>7}  {_sources(r)}"
        )
    lines.append("speed-ups (frame p50 and p95, slower / faster; peak MB faster vs slower side):")
    for c in report.get("comparisons") or comparisons(results):
        fast_mb, slow_mb = c["peak_rss_mb"]
        lines.append(
            f"  {c['strategy']}: {c['comparison']}: {c['speedup_p50']:.2f}x p50, "
            f"{c['speedup_p95']:.2f}x p95; peak {fast_mb:.0f} vs {slow_mb:.0f} MB"
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
