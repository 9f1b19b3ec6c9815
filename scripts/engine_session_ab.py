"""ONNX Runtime session settings on the extractor engines: memory arena off/on x 1/2 intra-op
threads, each case in a fresh process (peak RSS = that process's ru_maxrss), median of 5 runs on
the demo tile resized to 1024 px (DISK) or 640 px (XFeat). One JSON line per case.

    .venv/bin/python scripts/engine_session_ab.py all .engines
    .venv/bin/python scripts/engine_session_ab.py one ".engines/disk_depth*.onnx" 0 2 5
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def run_case(pattern: str, arena: bool, threads: int, runs: int) -> dict[str, Any]:
    import cv2
    import onnxruntime as ort

    from c3_matcher.engines.extract import image_to_feeds
    from c3_matcher.engines.runtime import SessionSettings

    where = Path(pattern)
    path = sorted(where.parent.glob(where.name))[0]
    options = SessionSettings(enable_cpu_mem_arena=arena, intra_op_num_threads=threads).build()
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    size = 1024 if path.name.startswith("disk") else 640
    tile = cv2.imread(str(REPO / "data" / "demo" / "tile_a.png"))[:, :, ::-1]
    rgb = np.ascontiguousarray(cv2.resize(tile, (size, size)))
    feeds = image_to_feeds(rgb, np.ones((size, size), bool))
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        session.run(None, feeds)
        times.append(time.perf_counter() - start)
    return {
        "engine": path.name,
        "arena": arena,
        "threads": threads,
        "ms_median": round(1e3 * float(np.median(times)), 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main(argv: list[str]) -> int:
    if argv[0] == "one":
        pattern, arena, threads, runs = argv[1], argv[2] == "1", int(argv[3]), int(argv[4])
        print(json.dumps(run_case(pattern, arena, threads, runs)))
        return 0
    directory = argv[1]
    for pattern in (f"{directory}/disk_depth*.onnx", f"{directory}/xfeat_default*.onnx"):
        for arena in ("0", "1"):
            for threads in ("1", "2"):
                args = [sys.executable, __file__, "one", pattern, arena, threads, "5"]
                out = subprocess.run(args, capture_output=True, text=True, check=False)
                print(out.stdout.strip() or out.stderr[-500:], flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
