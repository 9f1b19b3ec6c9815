"""Importing the contract modules loads no OpenCV, ONNX Runtime, pluggy or pydantic-settings."""

from __future__ import annotations

import subprocess
import sys

CONTRACT = [
    "c3_matcher.dto",
    "c3_matcher.errors",
    "c3_matcher.protocols",
    "c3_matcher.features",
    "c3_matcher.plugins.types",
]
HEAVY = ["cv2", "onnxruntime", "pluggy", "pydantic_settings"]


def test_contract_modules_load_nothing_heavy() -> None:
    code = (
        "import importlib, sys\n"
        f"for m in {CONTRACT!r}: importlib.import_module(m)\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
