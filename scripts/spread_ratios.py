"""How widely each fix's inliers spread: the figures behind RANSAC's ``MIN_SPREAD_RATIO``.

    .venv/bin/python scripts/spread_ratios.py EVAL_OUT [EVAL_OUT ...]

EVAL_OUT is a ``c3-matcher eval`` output directory (its ``<flight>/<strategy>/results.jsonl``,
with correspondences, the default). For every candidate kept in every frame it takes the
smaller of the two sides' spread ratios (``c3_matcher.ransac.spread_ratio``: how wide against
how long the inliers lie, 0 on one line) and prints, per strategy, the lowest ratio of the best
candidates that were the true tile, of every candidate kept with 60 inliers or more, and the
threshold under which RANSAC refuses a set.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from c3_matcher.ransac import MIN_SPREAD_RATIO, spread_ratio


def _ratio(rows: list[list[float]]) -> float:
    points = np.asarray(rows, dtype=np.float64)
    return min(spread_ratio(points[:, 0:2]), spread_ratio(points[:, 2:4]))


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    correct: dict[str, list[float]] = defaultdict(list)
    kept: dict[str, list[float]] = defaultdict(list)
    for out in map(Path, argv):
        for results in sorted(out.glob("*/*/results.jsonl")):
            strategy = results.parent.name
            for line in results.read_text().splitlines():
                frame = json.loads(line)
                candidates = (frame.get("result") or {}).get("per_candidate") or []
                for n, candidate in enumerate(candidates):
                    rows = candidate.get("inlier_correspondences") or []
                    if len(rows) >= 60:
                        kept[strategy].append(_ratio(rows))
                    if n == 0 and frame.get("correct") and rows:
                        correct[strategy].append(_ratio(rows))
    print(f"refused under {MIN_SPREAD_RATIO}")
    for strategy in sorted(kept.keys() | correct.keys()):
        best = correct[strategy]
        lowest = f"{min(best):.3f} ({len(best)} frames)" if best else "none"
        sets = kept[strategy]
        low = f"{min(sets):.3f} ({len(sets)} sets)" if sets else "none"
        print(f"{strategy:18s} true-tile best: {lowest:20s} sets of 60+ inliers: {low}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
