"""Print a short human summary of a ``c3-matcher match`` JSON result (used by scripts/demo).

    python scripts/summarize_match.py RESULT.json [DEMO.json]

With the demo's DEMO.json it also says whether the best candidate is the true tile.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    result = json.loads(Path(argv[0]).read_text())
    truth = json.loads(Path(argv[1]).read_text()) if len(argv) > 1 else None
    if "error" in result:
        print(f"{result['error']}: {result['message']}")
        return 3
    print(f"matcher: {result['matcher_label']}   frame: {result['frame_id']}")
    print(f"candidates: {result['candidates_input']} in, {result['candidates_dropped']} dropped")
    for rank, c in enumerate(result["per_candidate"]):
        mark = ""
        if truth is not None:
            mark = "  <- true tile" if truth["tiles"][c["tile_index"]]["true"] else ""
        print(
            f"  #{rank} --tile {c['tile_index']} {c['tile_id'] or ''}: "
            f"{c['inlier_count']} inliers, "
            f"{c['ransac_outlier_count']} outliers, median residual "
            f"{c['per_candidate_residual_px']:.2f} px{mark}"
        )
    if "centre_lat" in result:
        print(f"frame centre: lat {result['centre_lat']:.6f}, lon {result['centre_lon']:.6f}")
    if "viz" in result:
        print(f"picture: {result['viz']}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
