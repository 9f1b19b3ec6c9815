"""Two builds of one extractor engine, interleaved in one process on the same inputs: the mean
and median latency over the sizes a flight's rectified queries have (a new shape each frame,
256-416 px a side) and at fixed demo sizes, plus whether their features agree bit for bit
(keypoints, scores, descriptors; padding rows, score 0, dropped as the product drops them).
For deciding an export rewrite on the CPU provider (two intra-op threads, arena on, as the
product runs them).

    .venv/bin/python scripts/engine_ab.py OLD.onnx NEW.onnx
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from c3_matcher.engines.extract import select_keypoints

REPO = Path(__file__).resolve().parents[1]
IMAGE = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20150926.tif"
QUERY_SIDES = range(256, 448, 32)
FIXED = ((480, 640), (512, 512), (704, 928))  # (height, width): the image is 934 x 723


def session(path: str) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    options.enable_cpu_mem_arena = True
    options.enable_mem_pattern = False
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def feeds(rgb: np.ndarray, h: int, w: int) -> dict[str, np.ndarray]:
    image = rgb[:h, :w].transpose(2, 0, 1)[None].astype(np.float32) / 255.0
    return {"image": np.ascontiguousarray(image), "mask": np.ones((1, 1, h, w), np.float32)}


def main(old: str, new: str) -> None:
    rgb = cv2.imread(str(IMAGE))[:, :, ::-1]
    sessions = {"old": session(old), "new": session(new)}
    cases = {"query sizes": [(h, w) for h in QUERY_SIDES for w in QUERY_SIDES]}
    cases.update({f"{w}x{h}": [(h, w)] * 10 for h, w in FIXED})
    for name, shapes in cases.items():
        times: dict[str, list[float]] = {k: [] for k in sessions}
        agree = True
        for h, w in shapes:
            inputs = feeds(rgb, h, w)
            outs = {}
            for key, s in sessions.items():
                started = time.perf_counter()
                outs[key] = s.run(None, inputs)
                times[key].append(time.perf_counter() - started)
            kept = {k: select_keypoints(*o, max_keypoints=1 << 20) for k, o in outs.items()}
            agree &= all(map(np.array_equal, kept["old"], kept["new"]))
        line = ", ".join(
            f"{k} mean {1e3 * np.mean(v):.1f} median {1e3 * np.median(v):.1f} ms"
            for k, v in times.items()
        )
        print(f"{name} ({len(shapes)} runs): {line}; features identical: {agree}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
