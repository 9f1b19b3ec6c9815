"""A calibration made for another image size is bad input: ``match`` and ``replay`` exit 2 with
one line naming both sizes (``match`` ran the matcher and failed as a backbone error, exit 1;
``replay`` recorded a backbone error on every frame)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "demo"


def _refused(args: list[str], tmp_path: Path, needle: str) -> str:
    """Run ``c3-matcher ARGS`` (no engines: refused before any loads); assert exit 2, nothing
    on stdout and exactly one stderr line holding ``needle``; return that line."""
    proc = run_cli(
        *args,
        cwd=tmp_path,
        engine_dir=tmp_path,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
        timeout=300,
    )
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if needle in ln]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def _calibration_for_double_size(path: Path) -> tuple[int, int]:
    """Rewrite the calibration at ``path`` for an image twice as large; return the true size."""
    calibration = json.loads(path.read_text())
    w, h = calibration["image_size"]
    calibration["image_size"] = [w * 2, h * 2]
    path.write_text(json.dumps(calibration))
    return w, h


def test_match_with_a_calibration_for_another_image_size_exits_2_naming_both(tmp_path):
    cal = tmp_path / "cal.json"
    shutil.copy(DEMO / "calibration.json", cal)
    w, h = _calibration_for_double_size(cal)
    assert (w, h) == (640, 480)  # the demo frame's size
    tile = json.loads((DEMO / "demo.json").read_text())["tiles"][0]
    args = ["match", "--query", str(DEMO / "frame.jpg"), "--calibration", str(cal)]
    args += ["--tile", str(DEMO / tile["file"]), "--tile-id", ",".join(map(str, tile["tile_id"]))]
    line = _refused(args, tmp_path, "1280x960")
    assert "640x480" in line and "--calibration" in line and "scale K and image_size" in line


def test_replay_of_a_dataset_whose_calibration_is_for_another_size_exits_2(tmp_path):
    dataset = tmp_path / "flight"
    shutil.copytree(REPO / "data" / "flights" / "naip_demo", dataset)
    w, h = _calibration_for_double_size(dataset / "calibration.json")
    line = _refused(["replay", str(dataset), "--limit", "1"], tmp_path, f"{w * 2}x{h * 2}")
    assert f"{w}x{h}" in line and "calibration.json" in line and "scale K and image_size" in line
    assert not (tmp_path / "out").exists()  # nothing replayed
