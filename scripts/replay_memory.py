"""What replay and eval hold per frame until a run ends: each frame's result as JSON, its inlier
correspondences kept as the result's float32 arrays, beside the same results held as lists of
floats (as ``results.jsonl`` writes them, and as runs held them until 2026-12-03).

    .venv/bin/python scripts/replay_memory.py [FLIGHT_DIR] [--strategy NAME] [--frames N]

Flies ``--frames`` frames (default 20) of the flight (default ``data/flights/naip_demo``) with
the strategy (default ``xfeat``, the quickest), then measures with ``tracemalloc`` what a copy
of the held results takes in each form. Printed: KiB a matched frame, mean inliers a candidate.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import tempfile
import tracemalloc
from pathlib import Path
from typing import Any

from c3_matcher.compose import build_plugin_host
from c3_matcher.config import C3Settings
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import fly


def _held_kib(results: list[dict[str, Any]]) -> float:
    """KiB a result, measured on a deep copy (what holding ``results`` costs)."""
    tracemalloc.start()
    kept = copy.deepcopy(results)
    size, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    del kept
    return size / len(results) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("flight", nargs="?", type=Path, default=Path("data/flights/naip_demo"))
    parser.add_argument("--strategy", default="xfeat")
    parser.add_argument("--frames", type=int, default=20)
    args = parser.parse_args()
    flight = load_dataset(args.flight)
    flight = dataclasses.replace(flight, frames=flight.frames[: args.frames])
    with tempfile.TemporaryDirectory() as out:
        run = fly(C3Settings(), args.strategy, flight, Path(out), plugin_host=build_plugin_host())
    held = [o.result for o in run.outcomes if o.result]
    if not held:
        raise SystemExit("no frame matched: nothing is held")
    as_lists = [o.to_json()["result"] for o in run.outcomes if o.result]
    candidates = [c for r in held for c in r["per_candidate"]]
    inliers = sum(len(c["inlier_correspondences"]) for c in candidates) / len(candidates)
    print(f"{args.strategy}, {len(held)} matched frames, {inliers:.0f} inliers a candidate:")
    print(f"  held as arrays (now): {_held_kib(held):.1f} KiB a frame")
    print(f"  held as lists:        {_held_kib(as_lists):.1f} KiB a frame")


if __name__ == "__main__":
    main()
