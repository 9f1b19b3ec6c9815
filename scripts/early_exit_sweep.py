"""Measure the unmatchable-pair exit of adaptive LightGlue (``[lightglue] exit_matchable``) on
flights: one run per (strategy, flight) with the exit off records every pair's per-layer
trace (points kept, points whose matchability exceeds the match threshold, layers run) beside
the frame's outcome; every exit rule is then replayed on the traces, exactly, because an exit
returns no matches and a candidate with no matches is rejected (docs/decisions.md, "Pairs that
cannot match stop early").

A rule (``exit_after`` L, ``exit_matchable`` K) stops a pair after the first layer ``l >= L``
at which fewer than K points of either image are matchable. It changes a frame's outcome only
if it stops a pair whose candidate was accepted (``inlier_count >= min_inliers_threshold``);
the table gives, per rule, the pairs it stops, the layers it saves, and the accepted pairs it
would have stopped (must be 0 on every flight for a default), with the smallest margin.

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

from loguru import logger

from c3_matcher.config import load_settings
from c3_matcher.engines.lightglue import OnnxLightGlueRuntime
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.replay import build_matcher, run_flight

RULES_AFTER = (1, 2, 3)
RULES_MATCHABLE = (8, 16, 24, 32, 48, 64)


@contextmanager
def recording(pairs: list[dict[str, Any]]) -> Iterator[None]:
    """Record ``last_run`` and the kept match count of every LightGlue pair (experiment only)."""
    original = OnnxLightGlueRuntime.match_pair

    def recorded(self: OnnxLightGlueRuntime, *args: Any, feature_type: str) -> Any:
        raw = original(self, *args, feature_type=feature_type)
        pairs.append({**self.last_run, "matches": len(raw.matches)})
        return raw

    OnnxLightGlueRuntime.match_pair = recorded  # type: ignore[method-assign]
    try:
        yield
    finally:
        OnnxLightGlueRuntime.match_pair = original  # type: ignore[method-assign]


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
        update={"lightglue": settings.lightglue.model_copy(update={"exit_matchable": 0})}
    )
    dataset = load_dataset(flight)
    pairs: list[dict[str, Any]] = []
    starts: list[int] = []
    scratch = Path(f"/tmp/early_exit_sweep_{os.getpid()}")
    started = time.perf_counter()
    with recording(pairs), build_matcher(settings, strategy, scratch) as matcher:
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


def fires(pair: dict[str, Any], after: int, matchable: int) -> int | None:
    """The layer count at which the rule stops ``pair`` (None: it runs as recorded)."""
    for layer, (a, b) in enumerate(zip(pair["matchable0"], pair["matchable1"], strict=True)):
        if layer >= after and min(a, b) < matchable:
            return layer + 1
    return None


def _pair_inliers(frame: dict[str, Any]) -> list[int | None]:
    """Each pair's candidate inlier count, in order (None where pairs and candidates differ in
    number: rotation search or a dropped candidate; such a pair counts as accepted)."""
    pairs, candidates = frame["pairs"], frame["candidates"]
    if len(pairs) == len(candidates):
        return [c["inliers"] for c in candidates]
    if not candidates and frame["status"] == "insufficient":
        return [frame["insufficient_best"]] * len(pairs)  # an upper bound for every pair
    return [None] * len(pairs)


def replay_rules(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every rule replayed on every recorded pair of ``runs``."""
    rows = []
    for after in RULES_AFTER:
        for matchable in RULES_MATCHABLE:
            stopped = saved = layers = harmful = 0
            margin: int | None = None
            for run in runs:
                need = run["min_inliers_threshold"]
                for frame in run["frames"]:
                    for pair, inliers in zip(frame["pairs"], _pair_inliers(frame), strict=True):
                        layers += pair["layers"] or 0
                        stop = fires(pair, after, matchable)
                        accepted = inliers is None or inliers >= need
                        if accepted:
                            lowest = min(min(a, b) for a, b in zip(*_after(pair, after)))
                            margin = lowest if margin is None else min(margin, lowest)
                        if stop is None:
                            continue
                        stopped += 1
                        saved += pair["layers"] - stop
                        harmful += int(accepted)
            rows.append(
                {
                    "after": after,
                    "matchable": matchable,
                    "stopped": stopped,
                    "layers_saved": saved,
                    "layers": layers,
                    "stopped_accepted": harmful,
                    "accepted_min_matchable": margin,
                }
            )
    return rows


def _after(pair: dict[str, Any], after: int) -> tuple[list[int], list[int]]:
    m0, m1 = pair["matchable0"][after:], pair["matchable1"][after:]
    return (m0, m1) if m0 else ([10**9], [10**9])


def table(runs: list[dict[str, Any]]) -> str:
    pairs = sum(len(f["pairs"]) for r in runs for f in r["frames"])
    lines = [
        f"{len(runs)} flights, {pairs} pairs: "
        + ", ".join(f"{r['flight']} ({len(r['frames'])})" for r in runs),
        "| exit after layer | matchable < | pairs stopped | layers saved / run | stopped "
        "accepted | fewest matchable on an accepted pair |",
        "|---|---|---|---|---|---|",
    ]
    for row in replay_rules(runs):
        lines.append(
            f"| {row['after']} | {row['matchable']} | {row['stopped']} | "
            f"{row['layers_saved']} / {row['layers']} | {row['stopped_accepted']} | "
            f"{row['accepted_min_matchable']} |"
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
