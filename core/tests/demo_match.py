"""The README's demo frame matched by the OpenCV strategy (no engine needed), in-process or in
a child process of its own (for what a whole command run does: exit status, stdout, stderr)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2

from c3_matcher import Attitude, NavCameraFrame

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
FLIGHT = DEMO.parents[1] / "data" / "flights" / "naip_demo"  # the shipped demo flight
WINDOW = 448  # its candidates' store windows, px (the README's)
DEMO_MATCH = [
    "match",
    "--query",
    str(DEMO / "frame.jpg"),
    *("--tile", str(DEMO / "tile_a.png"), "--tile", str(DEMO / "tile_b.png")),
    *("--tile", str(DEMO / "tile_c.png"), "--tile-gsd", "0.09682870211490897"),
    *("--calibration", str(DEMO / "calibration.json"), "--attitude", "18,0,120"),
    *("--height", "27.112037", "--strategy", "sift_magsac", "--no-correspondences"),
]


def run_match(*extra: str, argv: Sequence[str] = DEMO_MATCH) -> subprocess.CompletedProcess[str]:
    """``c3-matcher`` with ``argv`` and ``extra`` run in a child process, no ``C3_MATCHER_*``
    variable of this one's environment given to it."""
    env = {k: v for k, v in os.environ.items() if not k.upper().startswith("C3_MATCHER_")}
    script = f"import sys\nfrom c3_matcher.cli import main\nsys.exit(main({[*argv, *extra]!r}))"
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env
    )


def flight_frame(index: int = 0) -> tuple[NavCameraFrame, dict[str, Any]]:
    """Frame ``index`` of the demo flight as the README's example makes it, and its record
    (``frames.jsonl``: its candidates, truth)."""
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[index])
    image = cv2.cvtColor(cv2.imread(str(FLIGHT / record["image"])), cv2.COLOR_BGR2RGB)
    frame = NavCameraFrame(
        frame_id=uuid.UUID(record["frame_id"]),
        image=image,
        captured_at_ns=time.monotonic_ns(),
        attitude=Attitude.from_degrees(*record["attitude_deg"]),
        height_above_ground_m=record["height_m"],
    )
    return frame, record
