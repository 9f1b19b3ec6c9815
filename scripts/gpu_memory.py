"""Where a GPU matcher process's memory goes: GPU memory (``nvidia-smi``, this process) after a
bare CUDA session, after the matcher is composed, after its first match and after a whole
flight, for the configured strategy; one process per variant of the CUDA provider's settings.

    python scripts/gpu_memory.py [--data DIR] [--strategy NAME]   # every variant, a table
    python scripts/gpu_memory.py --variant NAME ...                 # one variant (a child)

Needs onnxruntime-gpu, built engines and nvidia-smi (docs/benchmarks.md, GPU)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
_CUDA = "CUDAExecutionProvider"
VARIANTS: dict[str, dict[str, str]] = {
    "defaults": {},
    "arena as requested": {
        "C3_MATCHER_ENGINES__PROVIDER_OPTIONS": json.dumps(
            {_CUDA: {"arena_extend_strategy": "kSameAsRequested"}}
        )
    },
    "arena limit 256 MiB": {"C3_MATCHER_ENGINES__GPU_MEM_LIMIT_BYTES": str(256 << 20)},
    "1024 keypoints": {"C3_MATCHER_MATCHER__MAX_KEYPOINTS": "1024"},
    "cuDNN heuristic search": {
        "C3_MATCHER_ENGINES__PROVIDER_OPTIONS": json.dumps(
            {_CUDA: {"cudnn_conv_algo_search": "HEURISTIC"}}
        )
    },
}


def gpu_mib() -> int:
    """This process's GPU memory (MiB) as nvidia-smi reports it; 0 when it lists none."""
    out = subprocess.run(
        ["nvidia-smi", "--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"],
        capture_output=True,
        text=True,
        check=False,
    ).stdout
    for line in out.splitlines():
        pid, _, mib = (p.strip() for p in line.partition(","))
        if pid == str(os.getpid()) and mib.isdigit():
            return int(mib)
    return 0


def match(matcher: Any, frame: Any, rerank: Any, calibration: Any) -> None:
    """One match; a frame refused for too few inliers counts like any other."""
    from c3_matcher.errors import InsufficientInliersError

    with contextlib.suppress(InsufficientInliersError):
        matcher.match(frame, rerank, calibration)


def child(data: Path, strategy: str) -> dict[str, int]:
    """The checkpoints of one variant, in this process."""
    import onnxruntime as ort

    from c3_matcher.config import load_settings
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.run.inputs import flight_inputs
    from c3_matcher_tools.run.matcher import Overrides, compose_matcher
    from c3_matcher_xfeat.mnn import SIMILARITY_GRAPH

    marks: dict[str, int] = {}
    bare = ort.InferenceSession(SIMILARITY_GRAPH.read_bytes(), providers=[_CUDA])
    a = np.ones((4, 8), np.float32)
    bare.run(None, {i.name: a for i in bare.get_inputs()})
    marks["bare CUDA session"] = gpu_mib()
    settings = Overrides().apply(load_settings(None), strategy)
    clock = MonotonicClock()
    fdr = JsonlFdrRecorder(Path(tempfile.mkdtemp(prefix="c3-gpu-")) / "fdr.jsonl", clock)
    matcher = compose_matcher(settings, fdr=fdr, clock=clock).matcher
    marks["composed"] = gpu_mib()
    with flight_inputs(data) as inputs:
        match(matcher, *inputs[0])
        marks["first match"] = gpu_mib()
        peak, times = marks["first match"], []
        for frame, rerank, calibration in inputs[1:]:
            started = time.perf_counter()
            match(matcher, frame, rerank, calibration)
            times.append(time.perf_counter() - started)
            peak = max(peak, gpu_mib())
    marks[f"peak over {len(inputs)} frames"] = peak
    if times:
        marks["frame p50 ms"] = round(float(np.median(times)) * 1000)
    return marks


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=REPO / "data" / "flights" / "naip_demo")
    p.add_argument("--strategy", default="disk_lightglue")
    p.add_argument("--variant", choices=sorted(VARIANTS))
    args = p.parse_args(argv)
    os.environ.setdefault("C3_MATCHER_ENGINES__PROVIDERS", '["CUDA", "CPU"]')
    if args.variant:
        print(json.dumps(child(args.data, args.strategy)))
        return 0
    rows: dict[str, dict[str, int] | str] = {}
    for name, env in VARIANTS.items():
        run = subprocess.run(
            [
                sys.executable,
                __file__,
                "--variant",
                name,
                "--data",
                str(args.data),
                "--strategy",
                args.strategy,
            ],
            env={**os.environ, **env},
            capture_output=True,
            text=True,
            check=False,
        )
        lines = run.stdout.strip().splitlines()
        rows[name] = json.loads(lines[-1]) if run.returncode == 0 and lines else run.stderr[-300:]
        print(name, rows[name], flush=True)
    print(f"\nGPU memory (MiB, this process, nvidia-smi), {args.strategy} on {args.data.name}:")
    for name, marks in rows.items():
        cells = (
            "  ".join(f"{k} {v}" for k, v in marks.items()) if isinstance(marks, dict) else marks
        )
        print(f"  {name:<24} {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
