"""A PX4 ULog whose estimator marks its own output invalid (``vehicle_global_position``'s
``lat_lon_valid`` / ``alt_valid``, PX4 1.16 on): once GNSS is rejected the estimate drifts on
while the receiver holds a good fix. Frames where the estimate is marked invalid take the
receiver's position (or altitude) and the import says so; a log whose estimate is invalid
throughout reads the receiver alone. Logs are written by the project's writer
(:mod:`c3_matcher_tools.testing.flightlogs`) over frames of the shipped demo flight, whose poses
are known, and imported as a user runs the command."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
HOME_HEIGHTS = "altitude - home altitude 500.0 m"


@pytest.fixture(scope="module")
def poses() -> list[fl.Pose]:
    return fl.flight_poses(DEMO, range(4))


def _import(tmp_path: Path, poses: list[fl.Pose], flaw: str) -> tuple[Any, dict[str, Any]]:
    """The dataset imported from a ULog written with ``flaw``, and the import's summary."""
    log = write_ulog(tmp_path / "flight.ulg", poses, flaws=(flaw,))
    images = tmp_path / "images"
    images.mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, images / f"IMG_{i:04d}.jpg")
    flight = tmp_path / "flight"
    cal, store = DEMO / "calibration.json", DEMO / "tiles.mbtiles"
    proc = run_cli("dataset", "import", images, log, cal, store, flight, "--json", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    return load_dataset(flight), json.loads(proc.stdout)


def _off_m(telemetry: dict[str, Any], p: fl.Pose) -> float:
    dn = (telemetry["lat"] - p.lat) * 111_320.0
    de = (telemetry["lon"] - p.lon) * 111_320.0 * math.cos(math.radians(p.lat))
    return math.hypot(dn, de)


def test_positions_the_estimator_marks_invalid_are_the_receiver_s(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """From 0.3 s before the second frame the estimate drifts (40 m/s) and is marked invalid;
    each of those frames took it, unflagged, 12 to 172 m off. Now they take the receiver's
    fix: the second frame too, though the estimate's last valid sample lies within the gap
    (never a sample interpolated across an invalid one)."""
    dataset, summary = _import(tmp_path, poses, "estimate_invalid")
    off = [_off_m(f.telemetry, p) for f, p in zip(dataset.frames, poses, strict=True)]
    assert max(off) < 0.05, off
    assert [f.height_m for f in dataset.frames] == pytest.approx([p.height_m for p in poses])
    assert summary["height_sources"] == {HOME_HEIGHTS: 4}
    assert summary["gnss_degraded"] == [] and summary["skipped"] == []
    said = [n for n in summary["notes"] if n.startswith("vehicle_global_position marks")]
    assert said == [
        "vehicle_global_position marks its position invalid (lat_lon_valid false) in 22 of its "
        "31 samples (101.8-106.0 s): frames there take the receiver's position "
        "(vehicle_gps_position) where it has a fix"
    ], summary["notes"]


def test_an_altitude_the_estimator_marks_invalid_is_the_receiver_s(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Around the second frame the estimate's altitude is 100 m off and marked invalid: its
    height was 880 m for 780 m. Now the frame keeps the estimate's position and takes the
    receiver's altitude."""
    dataset, summary = _import(tmp_path, poses, "altitude_invalid")
    assert [f.height_m for f in dataset.frames] == pytest.approx([p.height_m for p in poses])
    assert summary["height_sources"] == {HOME_HEIGHTS: 4}
    off = [_off_m(f.telemetry, p) for f, p in zip(dataset.frames, poses, strict=True)]
    assert max(off) < 0.05, off
    said = [n for n in summary["notes"] if n.startswith("vehicle_global_position marks")]
    assert said == [
        "vehicle_global_position marks its altitude invalid (alt_valid false) in 3 of its 31 "
        "samples (101.8-102.2 s): frames there take the receiver's altitude"
    ], summary["notes"]


def test_an_estimate_marked_invalid_throughout_leaves_the_receiver(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """One frame, its estimate never valid: the track has no estimate and says why."""
    track = read_ulog(write_ulog(tmp_path / "f.ulg", poses[:1], flaws=("estimate_invalid",)))
    assert track.position is None and track.gnss is not None
    assert (
        "vehicle_global_position marks every position invalid: positions from "
        "vehicle_gps_position" in track.notes
    ), track.notes


def test_a_log_without_validity_fields_reads_its_estimate_as_before(
    poses: list[fl.Pose], tmp_path: Path
) -> None:
    """Older PX4 states no validity: every estimate sample is its position, nothing said."""
    track = read_ulog(write_ulog(tmp_path / "f.ulg", poses))
    assert track.position is not None and len(track.position) == 31
    assert bool((track.position.values == track.position.values).all())  # no NaN
    assert not [n for n in track.notes if "invalid" in n], track.notes
