"""Measure photometric normalisation x LightGlue filter threshold x final refit per strategy on
flights, paying for the feature work once per photometric setting (docs/precision.md).

For one strategy and one photometric setting, every variant (filter threshold, refit) runs the
real pipeline over every flight given, through the same ``run_flight`` and ``metrics`` as
``c3-matcher eval``. What makes it affordable on a CPU: the extractor outputs are memoised by
the bytes of the prepared image, and LightGlue's raw output (every mutual match with its
confidence) by the bytes of the keypoints and descriptors, so a second threshold re-runs only
the cheap tail (threshold filter, prior, RANSAC, checks, ranking). Applying the threshold to
the memoised raw output keeps exactly the matches ``OnnxLightGlueRuntime.match_pair`` keeps at
that threshold (``mscores0 > threshold``, ascending set-0 index), so every variant's numbers
are those ``eval`` gives with the same settings. Results: one JSON per (variant, flight) under
OUT; an existing one is read back, not re-run.

    C3_MATCHER_ENGINES__DIRECTORY=/work/engines-baseline nice -n 5 .venv/bin/python \\
        scripts/precision_sweep.py --strategy disk_lightglue --photometric clahe \\
        --threshold 0.01 --threshold 0.1 --refit none --refit tight --out RUNS data/flights/*
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from loguru import logger

from c3_matcher.config import C3Settings, load_settings
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
from c3_matcher.features import Features, RawMatches
from c3_matcher.ransac import REFIT_MODES, OpenCvRansacFilter, refit
from c3_matcher.strategy import ExtractorBackend
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.evaluate import metrics
from c3_matcher_tools.replay import build_matcher, run_flight


def _digest(*parts: Any) -> str:
    h = hashlib.blake2b(digest_size=20)
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(repr((p.dtype.str, p.shape)).encode())
            h.update(np.ascontiguousarray(p).tobytes())
        else:
            h.update(repr(p).encode())
    return h.hexdigest()


class Memo:
    """Extractor and raw-LightGlue memo, installed by patching the two classes (experiment
    only); ``refit_mode`` is applied after every RANSAC filter call."""

    def __init__(self) -> None:
        self.features: dict[str, Features] = {}
        self.raw: dict[str, RawMatches] = {}
        self.refit_mode = "none"
        self.refit_factor = 0.5
        self.refit_floor = 4
        self.hits = 0
        self.misses = 0

    def clear(self) -> None:
        self.features.clear()
        self.raw.clear()

    @contextmanager
    def installed(self) -> Iterator[None]:
        extract = ExtractorBackend.extract
        match_pair = OnnxLightGlueRuntime.match_pair
        ransac = OpenCvRansacFilter.filter
        memo = self

        def cached_extract(self: ExtractorBackend, image: Any) -> Features:
            key = _digest(
                str(self._config.extractor_engine_path),
                self._config.max_keypoints,
                image.image,
                image.valid,
            )
            if key not in memo.features:
                memo.misses += 1
                memo.features[key] = extract(self, image)
            else:
                memo.hits += 1
            return memo.features[key]

        def cached_match(self: OnnxLightGlueRuntime, *args: Any, feature_type: str) -> RawMatches:
            key = _digest(feature_type, *args)
            if key not in memo.raw:
                kept = self._threshold
                self._threshold = 0.0
                try:
                    memo.raw[key] = match_pair(self, *args, feature_type=feature_type)
                finally:
                    self._threshold = kept
            raw = memo.raw[key]
            keep = raw.scores > np.float32(self._threshold)
            return RawMatches(
                np.ascontiguousarray(raw.matches[keep]), np.ascontiguousarray(raw.scores[keep])
            )

        def refitted(self: OpenCvRansacFilter, correspondences: Any, threshold_px: float) -> Any:
            result = ransac(self, correspondences, threshold_px)
            return refit(
                result,
                memo.refit_mode,
                threshold_px,
                factor=memo.refit_factor,
                floor=memo.refit_floor,
            )

        patches: list[tuple[type, str, Callable[..., Any]]] = [
            (ExtractorBackend, "extract", cached_extract),
            (OnnxLightGlueRuntime, "match_pair", cached_match),
            (OpenCvRansacFilter, "filter", refitted),
        ]
        originals = [(cls, name, getattr(cls, name)) for cls, name, _ in patches]
        try:
            for cls, name, fn in patches:
                setattr(cls, name, fn)
            yield
        finally:
            for cls, name, fn in originals:
                setattr(cls, name, fn)


def _variant_settings(
    base: C3Settings, photometric: str, threshold: float, options: dict[str, Any] | None
) -> C3Settings:
    matcher = base.matcher.model_copy(update={"photometric": photometric})
    if options is not None:
        matcher = matcher.model_copy(update={"options": options})
    lightglue = base.lightglue.model_copy(update={"filter_threshold": threshold})
    return base.model_copy(update={"matcher": matcher, "lightglue": lightglue})


def _row(flight: str, m: dict[str, Any], outcomes: list[Any], wall_s: float) -> dict[str, Any]:
    present = [o for o in outcomes if o.has_truth and o.true_present]
    correct_inliers = [o.best_inliers for o in present if o.correct]
    return {
        "flight": flight,
        "correct": m["C3-IT-04"]["correct"],
        "present": m["C3-IT-04"]["frames"],
        "it01_p5": m["C3-IT-01"]["p5_best_inliers"],
        "it03_p95_px": m["C3-IT-03"]["p95_mean_error_px"],
        "it03_median_px": m["C3-IT-03"]["median_mean_error_px"],
        "it05_raised": m["C3-IT-05"]["insufficient"],
        "absent": m["C3-IT-05"]["absent_frames"],
        "false_confident": m["false_confident"]["count"],
        "scored": m["false_confident"]["of"],
        "other_tile": len(m["false_confident"]["right_fix_other_tile"]),
        "min_correct_inliers": min(correct_inliers) if correct_inliers else None,
        "per_frame": [
            {
                "index": o.index,
                "status": o.status,
                "correct": o.correct,
                "inliers": o.best_inliers,
                "error_px": o.mean_error_px if math.isfinite(o.mean_error_px) else None,
            }
            for o in outcomes
        ],
        "wall_s": wall_s,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("flights", type=Path, nargs="+")
    p.add_argument("--strategy", required=True)
    p.add_argument("--photometric", required=True, choices=["none", "grey", "clahe"])
    p.add_argument("--threshold", type=float, action="append", default=None)
    p.add_argument(
        "--refit",
        action="append",
        default=None,
        help=f"{' | '.join(REFIT_MODES)}[:FACTOR] (tight: keep inliers within FACTOR x the "
        "RANSAC threshold, default 0.5, never below [matcher] min_inliers_threshold)",
    )
    p.add_argument("--options", default=None, help="[matcher] options as JSON")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    logger.remove()  # the matchers' logs go to their own files (build_matcher), not stderr
    base = load_settings()
    thresholds = args.threshold or [base.lightglue.filter_threshold or 0.1]
    refits = args.refit or ["none"]
    options = json.loads(args.options) if args.options else None
    memo = Memo()
    tag = args.options and _digest(args.options)[:8]
    with memo.installed():
        for path in args.flights:
            dataset = load_dataset(path)
            memo.clear()
            for threshold in thresholds:
                for mode in refits:
                    variant = f"{args.photometric}_t{threshold:g}_{mode.replace(':', '')}"
                    variant += f"_{tag}" if tag else ""
                    target = args.out / args.strategy / variant / f"{dataset.name}.json"
                    if target.exists():
                        continue
                    memo.refit_mode, _, factor = mode.partition(":")
                    if memo.refit_mode not in REFIT_MODES:
                        p.error(f"--refit {mode}: not one of {REFIT_MODES}")
                    memo.refit_factor = float(factor or 0.5)
                    memo.refit_floor = base.matcher.min_inliers_threshold
                    settings = _variant_settings(base, args.photometric, threshold, options)
                    started = time.perf_counter()
                    scratch = Path(f"/tmp/precision_sweep_{os.getpid()}")
                    with build_matcher(settings, args.strategy, scratch) as m:
                        outcomes = run_flight(m, dataset)
                    wall = time.perf_counter() - started
                    row = _row(dataset.name, metrics(outcomes, []), outcomes, wall)
                    row.update(strategy=args.strategy, variant=variant, options=args.options)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    target.write_text(json.dumps(row, indent=1, default=_nan_none) + "\n")
                    print(
                        f"{args.strategy} {variant} {dataset.name}: {row['correct']}/"
                        f"{row['present']} IT-01 {row['it01_p5']:.0f} IT-03 "
                        f"{row['it03_p95_px']:.2f} fc {row['false_confident']} "
                        f"({wall:.0f} s, memo hits {memo.hits} misses {memo.misses})",
                        flush=True,
                    )
    return 0


def _nan_none(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else str(value)


if __name__ == "__main__":
    sys.exit(main())
