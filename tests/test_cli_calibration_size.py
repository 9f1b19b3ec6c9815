"""A calibration made for another image size is bad input: ``match`` and ``replay`` exit 2 with
one line naming both sizes (``match`` ran the matcher and failed as a backbone error, exit 1;
``replay`` recorded a backbone error on every frame)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "demo"


def test_calibration_for_another_image_size_exits_2_naming_both_sizes(tmp_path):
    calibration = json.loads((DEMO / "calibration.json").read_text())
    assert calibration["image_size"] == [640, 480]  # the demo frame's size
    calibration["image_size"] = [1280, 960]
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(calibration))
    tile = json.loads((DEMO / "demo.json").read_text())["tiles"][0]
    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    env["C3_MATCHER_ENGINES__DIRECTORY"] = str(tmp_path)  # refused before any engine loads
    env["C3_MATCHER_FDR__PATH"] = str(tmp_path / "fdr.jsonl")
    args = ["match", "--query", str(DEMO / "frame.jpg"), "--calibration", str(cal)]
    args += ["--tile", str(DEMO / tile["file"]), "--tile-id", ",".join(map(str, tile["tile_id"]))]
    proc = subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    lines = [ln for ln in proc.stderr.splitlines() if "1280x960" in ln]
    assert len(lines) == 1 and "640x480" in lines[0] and "--calibration" in lines[0], proc.stderr


def test_replay_of_a_dataset_whose_calibration_is_for_another_size_exits_2(tmp_path):
    dataset = tmp_path / "flight"
    shutil.copytree(REPO / "data" / "flights" / "naip_demo", dataset)
    calibration = json.loads((dataset / "calibration.json").read_text())
    w, h = calibration["image_size"]
    calibration["image_size"] = [w * 2, h * 2]
    (dataset / "calibration.json").write_text(json.dumps(calibration))
    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    env["C3_MATCHER_ENGINES__DIRECTORY"] = str(tmp_path)  # refused before any engine loads
    proc = subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", "replay", str(dataset), "--limit", "1"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if f"{w * 2}x{h * 2}" in ln]
    assert len(lines) == 1 and f"{w}x{h}" in lines[0] and "calibration.json" in lines[0]
    assert not (tmp_path / "out").exists()  # nothing replayed
