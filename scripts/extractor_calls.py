"""Frame latency of one strategy over a flight, and the median time of its extractor calls:
for seeing what else in the process slows ONNX Runtime (run it with and without
``OPENBLAS_NUM_THREADS=1``, docs/benchmarks.md). The flight is run once to warm up, then frame
by frame.

    .venv/bin/python scripts/extractor_calls.py xfeat FLIGHT
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/extractor_calls.py xfeat FLIGHT
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from loguru import logger

from c3_matcher.config import load_settings
from c3_matcher.engines.runtime import OnnxInferenceRuntime
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import FlightOptions, open_matcher, run_flight


def main(strategy: str, flight: Path) -> None:
    logger.remove()  # the matcher's logs go to its own file
    extractor_s: list[float] = []
    run = OnnxInferenceRuntime.run

    def timed(self: OnnxInferenceRuntime, engine: Any, feeds: Mapping[str, Any]) -> Any:
        started = time.perf_counter()
        out = run(self, engine, feeds)
        if "image" in feeds:  # an extractor call (LightGlue graphs take keypoints)
            extractor_s.append(time.perf_counter() - started)
        return out

    OnnxInferenceRuntime.run = timed  # type: ignore[method-assign]
    dataset = load_dataset(flight)
    with (
        tempfile.TemporaryDirectory() as scratch,
        open_matcher(load_settings(), strategy, Path(scratch)) as matcher,
    ):
        run_flight(matcher, dataset)
        extractor_s.clear()
        frame_s = []
        for frame in dataset.frames:
            started = time.perf_counter()
            run_flight(matcher, dataset, FlightOptions([frame]))
            frame_s.append(time.perf_counter() - started)
    print(
        f"{strategy} {dataset.name}: frame p50 {1e3 * np.percentile(frame_s, 50):.0f} ms, "
        f"p95 {1e3 * np.percentile(frame_s, 95):.0f} ms; extractor calls p50 "
        f"{1e3 * np.median(extractor_s):.1f} ms ({len(extractor_s)} calls)"
    )


if __name__ == "__main__":
    main(sys.argv[1], Path(sys.argv[2]))
