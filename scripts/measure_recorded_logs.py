"""Figures of every recorded-log importer on its test flight: frames of the shipped demo flight
written as a PX4 ULog, an ArduPilot telemetry log and DataFlash log, ROS 2 bags (sqlite3,
compressed images; MCAP, raw images) and a DJI-style photo folder (EXIF/XMP), each imported
with ``c3-matcher dataset import`` and replayed with ``c3-matcher replay``; prints one line per
importer (frames, located, estimate minus telemetry p50 / p95 / max in metres).

    C3_MATCHER_ENGINES__DIRECTORY=... .venv/bin/python scripts/measure_recorded_logs.py \
        [--frames 12] [--strategy xfeat] [--out out/recorded-logs]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

from c3_matcher.serialize import load_calibration
from c3_matcher_tools.run.scoring import figure
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.flightlogs.dataflash import write_dataflash
from c3_matcher_tools.testing.flightlogs.exif import write_exif_photos
from c3_matcher_tools.testing.flightlogs.mavlink import write_tlog
from c3_matcher_tools.testing.flightlogs.rosbag import write_bag
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "flights" / "naip_demo"


def c3(*args: str) -> str:
    proc = subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", *args], capture_output=True, text=True
    )
    if proc.returncode:
        raise SystemExit(f"c3-matcher {' '.join(args)} failed: {proc.stderr[-2000:]}")
    return proc.stdout


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=12)
    p.add_argument("--strategy", default="xfeat")
    p.add_argument("--out", type=Path, default=Path("out/recorded-logs"))
    args = p.parse_args()
    out: Path = args.out
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    poses = fl.flight_poses(DEMO, range(args.frames))
    calibration = load_calibration(DEMO / "calibration.json")
    images = out / "images"
    images.mkdir()
    for i, pose in enumerate(poses):
        shutil.copyfile(pose.image, images / f"IMG_{i:04d}.jpg")
    cal, store = str(DEMO / "calibration.json"), str(DEMO / "tiles.mbtiles")
    sources = {
        "PX4 ULog": [str(images), str(write_ulog(out / "f.ulg", poses)), cal],
        "ArduPilot tlog": [str(images), str(write_tlog(out / "f.tlog", poses)), cal],
        "ArduPilot DataFlash": [str(images), str(write_dataflash(out / "f.bin", poses)), cal],
        "ROS 2 bag sqlite3": ["-", str(write_bag(out / "bag1", poses, calibration)), "-"],
        "ROS 2 bag MCAP": [
            "-",
            str(write_bag(out / "bag2", poses, calibration, storage="mcap", compressed=False)),
            "-",
        ],
        "photo EXIF/XMP": [str(write_exif_photos(out / "photos", poses)), "-", cal],
    }
    for n, (label, head) in enumerate(sources.items()):
        flight = out / f"flight{n}"
        extra = ["--ground-elevation", str(fl.GROUND_M)] if head[0] == "-" else []
        c3("dataset", "import", *head, store, str(flight), *extra)
        replay = out / f"replay{n}"
        report = json.loads(
            c3("replay", str(flight), "--strategy", args.strategy, "--out", str(replay), "--json")
        )
        rows = [json.loads(x) for x in (replay / "results.jsonl").read_text().splitlines()]
        errors = [r["telemetry_error_m"] for r in rows if r["telemetry_error_m"] is not None]
        print(
            f"{label:20} frames {report['frames']:3} located {len(errors):3} "
            f"estimate-telemetry m p50 {figure(report['telemetry_error_m_p50'], '.2f')} "
            f"p95 {figure(report['telemetry_error_m_p95'], '.2f')} "
            f"max {figure(max(errors, default=None), '.2f')}"
        )


if __name__ == "__main__":
    main()
