"""The extractor engines under one execution provider: latency (min and median of N runs, two
intra-op threads, arena off as the product runs them) on the demo tile, and the share of the
CPU provider's keypoints the provider finds (run the CPU provider first: it saves them).

OpenVINO's provider ships as its own onnxruntime distribution, so it runs from its own
environment (it cannot share a process with the project's onnxruntime):

    python3 -m venv /tmp/ov && /tmp/ov/bin/pip install onnxruntime-openvino==1.24.1 numpy \\
        opencv-python-headless
    .venv/bin/python scripts/openvino_ab.py CPUExecutionProvider 4
    /tmp/ov/bin/python scripts/openvino_ab.py OpenVINOExecutionProvider 4
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

REPO = Path(__file__).resolve().parents[1]
CASES = (("disk_depth*", 768), ("xfeat_default*", 640), ("aliked_n16_*", 768))


def main(provider: str, runs: int) -> None:
    tile = cv2.imread(str(REPO / "data" / "demo" / "tile_a.png"))[:, :, ::-1]
    for pattern, size in CASES:
        path = sorted((REPO / ".engines").glob(pattern + ".onnx"))[0]
        rgb = np.ascontiguousarray(cv2.resize(tile, (size, size)))
        options = ort.SessionOptions()
        options.intra_op_num_threads = 2
        options.enable_cpu_mem_arena = False
        options.enable_mem_pattern = False
        extra = {} if provider == "CPUExecutionProvider" else {"device_type": "CPU"}
        session = ort.InferenceSession(
            str(path), options, providers=[provider], provider_options=[extra]
        )
        image = (rgb.transpose(2, 0, 1)[None] / 255.0).astype(np.float32)
        mask = np.ones((1, 1, size, size), np.float32)
        feeds = {i.name: image if i.name == "image" else mask for i in session.get_inputs()}
        keypoints = session.run(None, feeds)[0]
        times = []
        for _ in range(runs):
            started = time.perf_counter()
            session.run(None, feeds)
            times.append(time.perf_counter() - started)
        saved = Path("/tmp") / f"openvino_ab_{pattern.strip('*_')}.npy"
        if provider == "CPUExecutionProvider":
            np.save(saved, keypoints)
        reference = {tuple(np.round(k, 2)) for k in np.load(saved).reshape(-1, 2)}
        found = {tuple(np.round(k, 2)) for k in keypoints.reshape(-1, 2)}
        print(
            f"{path.name[:20]} {size}px {provider} (onnxruntime {ort.__version__}): "
            f"min {1e3 * min(times):.0f} ms, median {1e3 * float(np.median(times)):.0f} ms; "
            f"CPU provider's keypoints found {len(reference & found) / len(reference):.4f}",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
