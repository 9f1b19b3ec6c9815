"""The README's integration-guide snippet runs as written (on the demo data, real engines)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _snippet() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Using it from Python") :]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "the integration guide has no python block"
    return match.group(1)


@pytest.mark.slow
def test_integration_snippet_runs_as_written(engine_dir: Path, tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    env["C3_MATCHER_ENGINES__DIRECTORY"] = str(engine_dir)
    env["C3_MATCHER_FDR__PATH"] = str(tmp_path / "fdr.jsonl")
    env["C3_MATCHER_MATCHER__MAX_KEYPOINTS"] = "1024"  # keeps the test quick on 2 cores
    proc = subprocess.run(
        [sys.executable, "-c", _snippet()],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    first = proc.stdout.splitlines()[0]  # best tile id, its inlier count, the (I, 4) shape
    found = re.search(r"(\d+) \((\d+), 4\)$", first)
    assert found and found.group(1) == found.group(2), proc.stdout
    assert (tmp_path / "fdr.jsonl").is_file()  # the durable recorder compose_root built
