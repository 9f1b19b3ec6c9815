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
are those ``eval`` gives with the same settings (``[matcher] photometric``, ``[lightglue]
filter_threshold``, ``[matcher] refit_threshold_px`` set explicitly per variant). Results: one
JSON per (variant, flight) under
OUT; an existing one is read back, not re-run.

    C3_MATCHER_ENGINES__DIRECTORY=/work/engines-baseline nice -n 5 .venv/bin/python \\
        scripts/precision_sweep.py --strategy disk_lightglue --photometric clahe \\
        --threshold 0.01 --threshold 0.1 --refit none --refit tight --out RUNS data/flights/*
"""

from __future__ import annotations

import argparse
import dataclasses
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
from c3_matcher.strategy import ExtractorBackend
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import open_matcher, run_flight
from c3_matcher_tools.run.acceptance import Acceptance, metrics


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
    only)."""

    def __init__(self) -> None:
        self.features: dict[str, Features] = {}
        self.raw: dict[str, RawMatches] = {}
        self.hits = 0
        self.misses = 0

    def clear(self) -> None:
        self.features.clear()
        self.raw.clear()

    @contextmanager
    def installed(self) -> Iterator[None]:
        extract = ExtractorBackend.extract
        match_pair = OnnxLightGlueRuntime.match_pair
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
            key = _digest(feature_type, *(part for side in args for part in side))
            if key not in memo.raw:
                kept = self.filter_threshold
                self.filter_threshold = 0.0
                try:
                    memo.raw[key] = match_pair(self, *args, feature_type=feature_type)
                finally:
                    self.filter_threshold = kept
            raw = memo.raw[key]
            keep = raw.scores > np.float32(self.filter_threshold)
            return RawMatches(
                np.ascontiguousarray(raw.matches[keep]), np.ascontiguousarray(raw.scores[keep])
            )

        patches: list[tuple[type, str, Callable[..., Any]]] = [
            (ExtractorBackend, "extract", cached_extract),
            (OnnxLightGlueRuntime, "match_pair", cached_match),
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
    base: C3Settings,
    photometric: str,
    threshold: float,
    refit_px: float,
    options: dict[str, Any] | None,
) -> C3Settings:
    matcher = base.matcher.model_copy(
        update={"photometric": photometric, "refit_threshold_px": refit_px}
    )
    if options is not None:
        matcher = matcher.model_copy(update={"options": options})
    lightglue = base.lightglue.model_copy(update={"filter_threshold": threshold})
    return base.model_copy(update={"matcher": matcher, "lightglue": lightglue})


def _row(flight: str, m: Acceptance, outcomes: list[Any], wall_s: float) -> dict[str, Any]:
    present = [o for o in outcomes if o.has_truth and o.true_present]
    correct_inliers = [o.best_inliers for o in present if o.correct]
    return {
        "flight": flight,
        **dataclasses.asdict(m.headline),
        "it01_p5": m.inlier_count.p5_best_inliers,
        "it03_median_px": m.inlier_error.median_mean_error_px,
        "other_tile": len(m.false_confident.right_fix_other_tile),
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
    p.add_argument("flights", type=Path, nargs="*")
    p.add_argument("--strategy", required=True)
    p.add_argument("--photometric", choices=["none", "grey", "clahe"])
    p.add_argument(
        "--table",
        action="store_true",
        help="print the markdown table of the results under OUT for --strategy (runs nothing)",
    )
    p.add_argument("--threshold", type=float, action="append", default=None)
    p.add_argument(
        "--refit",
        action="append",
        default=None,
        help="none | tight[:FACTOR]: the final refit off, or at FACTOR (default 0.5) x [matcher] "
        "ransac_threshold_px ([matcher] refit_threshold_px)",
    )
    p.add_argument("--options", default=None, help="[matcher] options as JSON")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    if args.table:
        print(table(args.out / args.strategy))
        return 0
    if not args.flights or args.photometric is None:
        p.error("FLIGHT... and --photometric are needed to run")
    logger.remove()  # the matchers' logs go to their own files (open_matcher), not stderr
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
                    kind, _, factor = mode.partition(":")
                    if kind not in ("none", "tight"):
                        p.error(f"--refit {mode}: not none or tight[:FACTOR]")
                    refit_px = 0.0
                    if kind == "tight":
                        refit_px = float(factor or 0.5) * base.matcher.ransac_threshold_px
                    settings = _variant_settings(
                        base, args.photometric, threshold, refit_px, options
                    )
                    started = time.perf_counter()
                    scratch = Path(f"/tmp/precision_sweep_{os.getpid()}")
                    with open_matcher(settings, args.strategy, scratch) as m:
                        outcomes = run_flight(m, dataset)
                        engines = _engine_files(m)
                    wall = time.perf_counter() - started
                    row = _row(dataset.name, metrics(outcomes, []), outcomes, wall)
                    row.update(
                        strategy=args.strategy,
                        variant=variant,
                        options=args.options,
                        engines=engines,
                    )
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


def _cell(row: dict[str, Any]) -> str:
    it01, it03 = row["it01_p5"], row["it03_p95_px"]
    p5 = "-" if it01 is None or not math.isfinite(it01) else f"{it01:.0f}"
    p95 = "-" if it03 is None or not math.isfinite(it03) else f"{it03:.2f}"
    wrong = f", **{row['false_confident']} wrong**" if row["false_confident"] else ""
    if not row["present"]:
        return f"IT-05 {row['it05_raised']}/{row['absent']}{wrong}"
    return f"{row['correct']}/{row['present']}, {p5}, {p95}{wrong}"


def table(root: Path) -> str:
    """Flight x variant: correct tile, IT-01 p5, IT-03 p95 (false-confident when any)."""
    rows: dict[str, dict[str, dict[str, Any]]] = {}
    for path in sorted(root.glob("*/*.json")):
        rows.setdefault(path.stem, {})[path.parent.name] = json.loads(path.read_text())
    variants = sorted({v for by in rows.values() for v in by})
    lines = [
        "| flight | " + " | ".join(variants) + " |",
        "|---|" + "---|" * len(variants),
    ]
    for flight, by in rows.items():
        cells = [_cell(by[v]) if v in by else "" for v in variants]
        lines.append(f"| {flight} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _engine_files(matcher: Any) -> dict[str, str]:
    """Engine file names the matcher loaded, by role (compare settings within one engine set)."""
    backend = getattr(matcher, "backend", None)
    facts = backend.provenance().get("engines", {}) if backend is not None else {}
    return {role: str(f.get("file", "")) for role, f in facts.items()}


def _nan_none(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else str(value)


if __name__ == "__main__":
    sys.exit(main())
