"""One ``c3-matcher bench`` case, timed in its own process (``python -m
c3_matcher_tools.bench_worker CASE RUNS DATA [--config FILE]``, one JSON line on stdout) so that
its peak memory is its own: the matcher opened through the run layer with the
case's overrides, 2 warm-up runs, then ``RUNS`` timed matches (ms) of the data's frames.

A frame whose match raised InsufficientInliersError is still timed (the matcher ran): its time
counts in ``frame_ms`` and its best inlier count as 0, and ``frames_raised`` counts it. Candidate
and stage times come from the diagnostics of a result, so only from frames that matched:
``per_candidate_ms`` is None when none did. ``peak_rss_mib``: the worker's own peak
(:func:`~c3_matcher_tools.memory.peak_rss_mib`). Bad input (``InvalidInputError``: a frame
that cannot be read, say) exits 2 with one JSON line ``{"field", "reason"}`` on stderr, never a
traceback; ``bench`` reports it as its own refusal."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.commands import EXIT_OK, EXIT_USAGE, bounded_int
from c3_matcher.config import C3Settings, load_settings
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.bench import BenchCase
from c3_matcher_tools.memory import peak_rss_mib
from c3_matcher_tools.run.inputs import flight_inputs
from c3_matcher_tools.run.matcher import Overrides, compose_matcher

__all__ = ["run_worker"]

STAGES = ("decode", "preprocess", "extract", "match", "ransac")
"""A candidate's stages listed whether or not it went through them (0 ms when not); the
others it records (``assemble`` of stored features, ``refine``) follow where it did."""


def _percentiles(values: list[float]) -> dict[str, float] | None:
    """p50 and p95 of ``values``; None when there is none."""
    if not values:
        return None
    arr = np.asarray(values, dtype=np.float64)
    return {"p50": float(np.percentile(arr, 50)), "p95": float(np.percentile(arr, 95))}


def _overrides(case: BenchCase) -> Overrides:
    """The case's settings over the configuration (the keypoint budget as the case has it)."""
    return Overrides(
        tile_cache_size=case.tile_cache_size,
        max_long_side=case.max_long_side,
        max_keypoints=case.max_keypoints,
        stored_features=case.stored_features,
        lightglue_mode=case.lightglue_mode,
        intra_op_threads=case.intra_op_threads,
    )


def run_worker(case: BenchCase, runs: int, data_dir: Path, settings: C3Settings) -> dict[str, Any]:
    """Time ``runs`` matches of the demo frame (after 2 warm-up runs) in this process."""
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.baselines import SIFT_LABEL

    strategy = SIFT_LABEL if case.kind == "sift" else case.strategy
    settings = _overrides(case).apply(settings, strategy)  # no budget: the configured one
    clock = MonotonicClock()
    limit = settings.matcher.max_image_pixels
    with (
        flight_inputs(data_dir, limit) as inputs,
        tempfile.TemporaryDirectory(prefix="c3-bench-") as tmp,
    ):
        fdr = JsonlFdrRecorder(Path(tmp) / "fdr.jsonl", clock)
        started = time.perf_counter()
        try:
            composed = compose_matcher(
                settings, fdr=fdr, clock=clock, reference=case.kind == "pytorch"
            )
        except LookupError as exc:
            raise SystemExit(str(exc)) from None
        startup_s = time.perf_counter() - started
        timed = _time_matches(composed.matcher, inputs, runs)
    peak_mib = peak_rss_mib()
    return {
        "case": asdict(case),
        "label": case.label,
        "provider": composed.provider,
        "runs": runs,
        "startup_s": startup_s,
        **timed,
        "peak_rss_mib": peak_mib,
    }


def _time_matches(matcher: Any, inputs: list[tuple[Any, Any, Any]], runs: int) -> dict[str, Any]:
    """Frame, candidate and stage times (ms) of ``runs`` matches after 2 warm-up runs, the
    median best inlier count, how many timed frames raised InsufficientInliersError and where
    the candidates' features came from (see the module docstring)."""
    from c3_matcher.errors import InsufficientInliersError

    frame_ms: list[float] = []
    candidate_ms: list[float] = []
    stages: dict[str, list[float]] = {s: [] for s in ("query_preprocess", "query_extract", *STAGES)}
    best: list[int] = []
    raised = 0
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
            raised += 1
            continue
        best.append(result.per_candidate[0].inlier_count)
        diag = result.diagnostics
        for source in diag.get("candidate_features", ()):
            sources[source] = sources.get(source, 0) + 1
        for key in ("query_preprocess", "query_extract"):
            stages[key].append(diag["timings_ms"][key])
        for cand in diag["per_candidate_timings_ms"]:
            candidate_ms.append(sum(cand.values()))  # every stage it went through
            for s in (*STAGES, *(k for k in cand if k not in STAGES)):
                stages.setdefault(s, []).append(cand.get(s, 0.0))
    return {
        "best_inliers": int(np.median(best)),
        "frames_raised": raised,
        "frame_ms": _percentiles(frame_ms),
        "per_candidate_ms": _percentiles(candidate_ms),  # None: no frame matched
        "stages_ms": {k: _percentiles(v) for k, v in stages.items() if v},
        "feature_sources": sources,
    }


def _worker_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m c3_matcher_tools.bench_worker")
    parser.add_argument("case", help="BenchCase as JSON")
    parser.add_argument("runs", type=bounded_int())
    parser.add_argument("data", type=Path)
    parser.add_argument("--config", type=Path, default=None)
    args = parser.parse_args(argv)
    from loguru import logger

    logger.remove()
    case = BenchCase(**json.loads(args.case))
    try:
        result = run_worker(case, args.runs, args.data, load_settings(args.config))
    except InvalidInputError as exc:  # bad input, never a traceback: the parent says it
        print(json.dumps({"field": exc.field, "reason": exc.reason}), file=sys.stderr)
        return EXIT_USAGE
    print(json.dumps(result))
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1:]))
