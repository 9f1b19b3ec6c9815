"""How strong each fix's rivals are and where they place the frame: the figures behind the
ambiguity check's ``AMBIGUITY_RATIO`` and ``AGREE_PX`` (``c3_matcher.stages.ambiguity``).

    .venv/bin/python scripts/ambiguity_ratios.py DATA EVAL_OUT [EVAL_OUT ...]

DATA is the folder of the flights evaluated (``data/flights``: each flight's calibration and
candidate size); EVAL_OUT a ``c3-matcher eval`` output directory (its
``<flight>/<strategy>/results.jsonl``, with correspondences, the default). For every frame with a
fix and more than one candidate kept it measures each rival as the check does (its share of the
best's inliers, how far apart the two place the frame, in the best tile's px) and prints, per
strategy, the strongest rival of one place with how far it was, and the strongest rival of
another place (farther than ``AGREE_PX``), against ``AMBIGUITY_RATIO``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.dto import TileId
from c3_matcher.serialize import load_calibration
from c3_matcher.stages.ambiguity import AGREE_PX, AMBIGUITY_RATIO, Placed, apart_m


def _placed(candidate: dict[str, Any], size: int) -> Placed:
    zoom, lat, lon = candidate["tile_id"]
    rows = np.asarray(candidate["inlier_correspondences"], np.float32).reshape(-1, 4)
    return Placed(rows, TileId(int(zoom), float(lat), float(lon)), (size, size), None)


def _rivals(data: Path, results: Path) -> list[tuple[float, float]]:
    """(share of the best's inliers, px apart) of every rival in ``results``' fixes."""
    flight = data / results.parent.parent.name
    size = int(json.loads((flight / "dataset.json").read_text())["candidate_size_px"])
    calibration = load_calibration(flight / "calibration.json")
    found = []
    for line in results.read_text().splitlines():
        kept = (json.loads(line).get("result") or {}).get("per_candidate") or []
        if len(kept) < 2:
            continue
        best = _placed(kept[0], size)
        for rival in kept[1:]:
            apart = apart_m(best, _placed(rival, size), calibration)
            if apart is not None:
                share = rival["inlier_count"] / kept[0]["inlier_count"]
                found.append((share, apart / best.tile_gsd_m))
    return found


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    data, outs = Path(argv[0]), [Path(a) for a in argv[1:]]
    by_strategy: dict[str, list[tuple[float, float]]] = {}
    for out in outs:
        for results in sorted(out.glob("*/*/results.jsonl")):
            by_strategy.setdefault(results.parent.name, []).extend(_rivals(data, results))
    print(f"ambiguous: a rival with {AMBIGUITY_RATIO} of the best's inliers, over {AGREE_PX} px")
    for strategy, rivals in sorted(by_strategy.items()):
        same = [r for r in rivals if r[1] <= AGREE_PX]
        other = [r for r in rivals if r[1] > AGREE_PX]
        near = max(same, default=(0.0, 0.0))
        far = max(other, default=(0.0, 0.0))
        print(
            f"{strategy:18s} {len(rivals):4d} rivals; one place: strongest {near[0]:.2f} "
            f"({near[1]:.1f} px apart), farthest {max((r[1] for r in same), default=0):.1f} px; "
            f"another place: strongest {far[0]:.2f} ({far[1]:.0f} px apart)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
