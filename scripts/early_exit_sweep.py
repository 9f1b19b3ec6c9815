"""Measure the unmatchable-pair exit of adaptive LightGlue (``[lightglue] exit_matches``) on
flights: one run per (strategy, flight) with the exit off records, for every LightGlue pair and
every layer before its last, the points of each image above each matchability level and the
mutual matches the assignment head gives above each confidence level, beside the frame's
outcome. Every rule is then replayed on the traces, exactly, because an exit returns no matches
and a candidate with no matches is rejected (docs/decisions.md, "Pairs that cannot match").

A rule (signal, level, after layer L, fewer than K) stops a pair after layer L when fewer than K
counts of the signal exceed the level, as ``AdaptiveLightGlue`` tests once (``exit_after``,
``exit_confidence``, ``exit_matches``). It changes a frame's outcome only if it stops a pair
whose candidate was accepted (``inlier_count >= min_inliers_threshold``); the table gives, per
rule, the pairs it stops, the layers it saves, the accepted pairs it would have stopped (must be
0 on every flight for a default) and the lowest count on an accepted pair (the margin).

    nice -n 5 .venv/bin/python scripts/early_exit_sweep.py --strategy disk_lightglue \\
        --out RUNS data/flights/naip_demo data/flights/naip_distractors ...
    .venv/bin/python scripts/early_exit_sweep.py --strategy disk_lightglue --out RUNS --table
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from loguru import logger

from c3_matcher.config import load_settings
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
from c3_matcher.engines.lightglue_adaptive import AdaptiveLightGlue
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import open_matcher, run_flight

LEVELS = (0.01, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9)
"""Matchability levels at which each layer's matchable points are counted."""
RULES_AFTER = (0, 1, 2, 3)
RULES_BELOW = (8, 16, 24, 32, 48, 64, 96, 128)


@contextmanager
def recording(pairs: list[dict[str, Any]]) -> Iterator[None]:
    """Record ``last_run``, the kept match count and, per layer, the points of each image whose
    matchability exceeds each of ``LEVELS`` for every LightGlue pair (experiment only)."""
    match_pair, after_layer = OnnxLightGlueRuntime.match_pair, AdaptiveLightGlue._after_layer
    levels: list[list[list[int]]] = []

    def recorded(self: OnnxLightGlueRuntime, *args: Any, feature_type: str) -> Any:
        levels.clear()
        raw = match_pair(self, *args, feature_type=feature_type)
        pairs.append({**self.last_run, "matches": len(raw.matches), "levels": list(levels)})
        return raw

    def observed(self: AdaptiveLightGlue, layer: int, out: Any, side0: Any, side1: Any) -> str:
        scores = self.mutual_scores(layer, side0, side1)
        levels.append(
            [
                [int((np.asarray(out[f"matchability{i}"]) > level).sum()) for level in LEVELS]
                for i in (0, 1)
            ]
            + [[int((scores > level).sum()) for level in LEVELS]]
        )
        return after_layer(self, layer, out, side0, side1)

    OnnxLightGlueRuntime.match_pair = recorded  # type: ignore[method-assign]
    AdaptiveLightGlue._after_layer = observed  # type: ignore[method-assign]
    try:
        yield
    finally:
        OnnxLightGlueRuntime.match_pair = match_pair  # type: ignore[method-assign]
        AdaptiveLightGlue._after_layer = after_layer  # type: ignore[method-assign]


class _FrameMarker:
    """Delegates to the matcher; tells ``pairs`` where each frame starts."""

    def __init__(self, matcher: Any, pairs: list[dict[str, Any]], starts: list[int]) -> None:
        self._matcher, self._pairs, self._starts = matcher, pairs, starts

    def match(self, *args: Any, **kwargs: Any) -> Any:
        self._starts.append(len(self._pairs))
        return self._matcher.match(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._matcher, name)


def record_flight(strategy: str, flight: Path) -> dict[str, Any]:
    """Run one flight with the exit off; every frame's pairs and candidates."""
    settings = load_settings()
    settings = settings.model_copy(
        update={"lightglue": settings.lightglue.model_copy(update={"exit_matches": 0})}
    )
    dataset = load_dataset(flight)
    pairs: list[dict[str, Any]] = []
    starts: list[int] = []
    scratch = Path(f"/tmp/early_exit_sweep_{os.getpid()}")
    started = time.perf_counter()
    with recording(pairs), open_matcher(settings, strategy, scratch) as matcher:
        outcomes = run_flight(_FrameMarker(matcher, pairs, starts), dataset)
    frames = []
    for n, outcome in enumerate(outcomes):
        end = starts[n + 1] if n + 1 < len(starts) else len(pairs)
        result = outcome.result or {}
        frames.append(
            {
                "index": outcome.index,
                "status": outcome.status,
                "correct": outcome.correct,
                "true_present": outcome.true_present,
                "candidates": [
                    {"tile_index": c["tile_index"], "inliers": c["inlier_count"]}
                    for c in sorted(result.get("per_candidate", []), key=lambda c: c["tile_index"])
                ],
                "candidates_input": len(dataset.frames[n].candidates),
                "best_tile_index": outcome.best_input_index,
                "insufficient_best": outcome.insufficient_best,
                "pairs": pairs[starts[n] : end],
            }
        )
    return {
        "flight": dataset.name,
        "strategy": strategy,
        "min_inliers_threshold": settings.matcher.min_inliers_threshold,
        "wall_s": time.perf_counter() - started,
        "frames": frames,
    }


SIGNALS = ("matchable", "matched")
"""matchable: the fewer of the two images' points above the matchability level; matched: the
mutual matches the assignment head gives at that layer above the confidence level."""


def count(step: list[list[int]], signal: str, level: int) -> int:
    """One layer's count for ``signal`` at ``LEVELS[level]``."""
    if signal == "matchable":
        return min(step[0][level], step[1][level])
    return step[2][level]


def fires(pair: dict[str, Any], rule: tuple[str, int, int, int]) -> int | None:
    """The layer count at which ``rule`` (signal, level, after, fewer-than) stops ``pair``:
    tested once, after layer ``after``, as ``AdaptiveLightGlue`` does (None: it runs as
    recorded)."""
    signal, level, after, below = rule
    steps = pair["levels"]
    if after < len(steps) and count(steps[after], signal, level) < below:
        return after + 1
    return None


def pair_inliers(frame: dict[str, Any]) -> list[int | None]:
    """Each pair's candidate inlier count, pairs in candidate order (0: rejected, so not in the
    result); None where the pairs are not one per candidate (such a pair counts as accepted)."""
    pairs = frame["pairs"]
    if len(pairs) != frame["candidates_input"]:
        return [None] * len(pairs)
    inliers = {c["tile_index"]: c["inliers"] for c in frame["candidates"]}
    return [inliers.get(k, 0) for k in range(len(pairs))]


def replay_rules(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every rule replayed on every recorded pair of ``runs``, safe ones (no accepted pair
    stopped) first, most layers saved first."""
    rows = [
        _replay(runs, (signal, level, after, below))
        for signal in SIGNALS
        for level in range(len(LEVELS))
        for after in RULES_AFTER
        for below in RULES_BELOW
    ]
    return sorted(rows, key=lambda r: (r["stopped_accepted"] > 0, -r["layers_saved"]))


def _replay(runs: list[dict[str, Any]], rule: tuple[str, int, int, int]) -> dict[str, Any]:
    signal, level, after, below = rule
    stopped = saved = layers = harmful = 0
    margin: int | None = None
    for run in runs:
        need = run["min_inliers_threshold"]
        for frame in run["frames"]:
            for pair, inliers in zip(frame["pairs"], pair_inliers(frame), strict=True):
                layers += pair["layers"] or 0
                accepted = inliers is None or inliers >= need
                counts = [count(step, signal, level) for step in pair["levels"][after : after + 1]]
                if accepted and counts:
                    margin = min(counts) if margin is None else min(margin, *counts)
                stop = fires(pair, rule)
                if stop is not None:
                    stopped += 1
                    saved += pair["layers"] - stop
                    harmful += int(accepted)
    return {
        "signal": signal,
        "level": LEVELS[level],
        "after": after,
        "below": below,
        "stopped": stopped,
        "layers_saved": saved,
        "layers": layers,
        "stopped_accepted": harmful,
        "accepted_min": margin,
    }


def table(runs: list[dict[str, Any]], top: int = 25) -> str:
    """The ``top`` rules (safe ones first, most layers saved first) as a markdown table."""
    pairs = sum(len(f["pairs"]) for r in runs for f in r["frames"])
    lines = [
        f"{len(runs)} flights, {pairs} pairs: "
        + ", ".join(f"{r['flight']} ({len(r['frames'])})" for r in runs),
        "| signal | level | after layer | fewer than | pairs stopped | layers saved / run "
        "| accepted pairs stopped | lowest count on an accepted pair |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in replay_rules(runs)[:top]:
        lines.append(
            f"| {row['signal']} | {row['level']} | {row['after']} | {row['below']} | "
            f"{row['stopped']} | {row['layers_saved']} / {row['layers']} | "
            f"{row['stopped_accepted']} | {row['accepted_min']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("flights", type=Path, nargs="*")
    p.add_argument("--strategy", required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--table", action="store_true", help="print the rule table (runs nothing)")
    args = p.parse_args(argv)
    folder = args.out / args.strategy
    if not args.table:
        logger.remove()  # the matcher's logs go to their own file (build_matcher)
        folder.mkdir(parents=True, exist_ok=True)
        for flight in args.flights:
            target = folder / f"{Path(flight).name}.json"
            if target.exists():
                continue
            run = record_flight(args.strategy, flight)
            target.write_text(json.dumps(run) + "\n")
            print(f"{args.strategy} {run['flight']}: {run['wall_s']:.0f} s", flush=True)
    runs = [json.loads(f.read_text()) for f in sorted(folder.glob("*.json"))]
    print(table(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
