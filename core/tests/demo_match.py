"""The README's demo frame matched by the OpenCV strategy (no engine needed), in-process or in
a child process of its own (for what a whole command run does: exit status, stdout, stderr)."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
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
