"""ONNX Runtime's telemetry is off wherever c3-matcher runs: starting it writes nothing under
HOME (a device id and an event database, before), unless the user asks for it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

START_ORT = (
    "import c3_matcher\n"
    "from c3_matcher.engines.providers import _onnxruntime_providers\n"
    "print(_onnxruntime_providers())\n"
)


def _home_files(home: Path, **env: str) -> list[Path]:
    clean = {k: v for k, v in os.environ.items() if k != "ORT_DISABLE_TELEMETRY"}
    subprocess.run(
        [sys.executable, "-c", START_ORT],
        env={**clean, "HOME": str(home), **env},
        check=True,
        capture_output=True,
        timeout=120,
    )
    return sorted(p for p in home.rglob("*") if p.is_file())


def test_starting_onnxruntime_writes_nothing_under_home(tmp_path: Path) -> None:
    assert _home_files(tmp_path) == []


def test_a_user_who_sets_the_variable_keeps_their_choice() -> None:
    env = {**os.environ, "ORT_DISABLE_TELEMETRY": "0"}
    code = "import os, c3_matcher; print(os.environ['ORT_DISABLE_TELEMETRY'])"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
    )
    assert out.stdout.strip() == "0"
