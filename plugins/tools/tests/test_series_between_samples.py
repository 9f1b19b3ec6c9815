"""A log value looked up between two of its samples: :meth:`Series.at` interpolates linearly
between the samples either side when both are within the gap, takes the nearer one when only
it is, gives None when neither is, and interpolates an angle the short way round (across
+-180 deg). On the real path, a PX4 ULog written by the kit (its position at 5 Hz, its attitude
once a frame) is imported with a ``--time-offset`` that puts every frame between the position's
samples and far from all but its own attitude sample; each frame's position, height and
attitude are checked against the poses the log was written from, computed here."""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.sources.track import Series
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
OFFSET_S = 0.05
"""A quarter of the kit's 0.2 s position interval: each frame a quarter of the way from one
position sample to the next (weights 0.75 and 0.25, which swapped give another place)."""


def _at(series: Series, t: float, max_gap_s: float) -> list[float]:
    value = series.at(t, max_gap_s)
    assert value is not None, f"no value at {t} s within {max_gap_s} s"
    return [float(v) for v in value]


def test_between_two_samples_the_value_is_interpolated_linearly() -> None:
    s = Series.build("x", [0.0, 1.0], [[0.0, 100.0], [10.0, 200.0]], source="log")
    assert _at(s, 0.25, 1.0) == pytest.approx([2.5, 125.0])
    assert _at(s, 0.75, 1.0) == pytest.approx([7.5, 175.0])
    assert _at(s, 0.5, 0.5) == pytest.approx([5.0, 150.0])  # both exactly at the gap


def test_with_only_one_sample_within_the_gap_the_nearer_is_taken() -> None:
    s = Series.build("x", [0.0, 10.0, 11.0], [[0.0], [100.0], [110.0]], source="log")
    assert _at(s, 0.5, 1.0) == [0.0]  # 10 s is 9.5 s away
    assert _at(s, 9.25, 1.0) == [100.0]  # 0 s is 9.25 s away
    assert _at(s, 10.25, 1.0) == pytest.approx([102.5])  # both within the gap again
    assert _at(s, -0.5, 1.0) == [0.0]  # before the first sample
    assert _at(s, 11.75, 1.0) == [110.0]  # after the last
    assert s.at(5.0, 1.0) is None  # neither within the gap
    assert s.at(12.5, 1.0) is None


def test_an_angle_is_interpolated_the_short_way_round() -> None:
    """Yaw 170 deg then -170 deg: 20 deg apart across +-180, not 340 deg through 0."""
    s = Series.build(
        "att", [0.0, 1.0], [[10.0, 0.0, 170.0], [20.0, 0.0, -170.0]], (2,), source="log"
    )
    assert _at(s, 0.25, 1.0) == pytest.approx([12.5, 0.0, 175.0])
    assert _at(s, 0.75, 1.0) == pytest.approx([17.5, 0.0, -175.0])
    assert abs(_at(s, 0.5, 1.0)[2]) == pytest.approx(180.0)


def _poses() -> list[fl.Pose]:
    """Four frames of the demo flight (2 s apart), climbing 10 m a frame so that the altitude
    too changes between samples."""
    poses = fl.flight_poses(DEMO, range(4))
    return [dataclasses.replace(p, height_m=p.height_m + 10.0 * i) for i, p in enumerate(poses)]


def _truth(poses: list[fl.Pose], t: float) -> tuple[float, float, float]:
    """(lat, lon, height m) at ``t`` s from the first frame: straight between frames, as the
    vehicle flies in the log; the last frame's place past it (the last sample, within the
    gap)."""
    for a, b in itertools.pairwise(poses):
        if a.t_s <= t < b.t_s:
            w = (t - a.t_s) / (b.t_s - a.t_s)
            return (
                a.lat + w * (b.lat - a.lat),
                a.lon + w * (b.lon - a.lon),
                a.height_m + w * (b.height_m - a.height_m),
            )
    last = poses[-1]
    return last.lat, last.lon, last.height_m


def test_an_imported_ulog_gives_frames_between_its_samples_their_values(tmp_path: Path) -> None:
    """Each frame 0.05 s after its trigger: its position a quarter of the way to the next
    position sample, its attitude its own frame's (the next attitude sample is 1.95 s away,
    past the default 1 s gap)."""
    poses = _poses()
    log = write_ulog(tmp_path / "flight.ulg", poses)
    images = fl.pose_images(tmp_path, poses)
    flight = tmp_path / "flight"
    proc = run_cli(
        "dataset", "import", str(images), str(log), str(DEMO / "calibration.json"),
        str(DEMO / "tiles.mbtiles"), str(flight), "--time-offset", str(OFFSET_S), cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "offset +0.050 s (given)" in proc.stdout
    frames = load_dataset(flight).frames
    assert len(frames) == len(poses)
    for f, p in zip(frames, poses, strict=True):
        lat, lon, height = _truth(poses, p.t_s + OFFSET_S)
        t = f.telemetry
        assert t["time_s"] == pytest.approx(fl.BOOT_S + p.t_s + OFFSET_S)
        assert (t["lat"], t["lon"]) == pytest.approx((lat, lon), abs=1e-9), f.index
        assert f.height_m == pytest.approx(height, abs=1e-3), f.index
        assert t["alt_m"] == pytest.approx(fl.GROUND_M + height, abs=1e-3), f.index
        assert np.allclose(f.attitude_deg, (p.roll, p.pitch, p.yaw), atol=1e-3), f.index
    for f, p in zip(frames[:-1], poses, strict=False):  # none on its trigger's own sample
        assert math.hypot(f.telemetry["lat"] - p.lat, f.telemetry["lon"] - p.lon) > 1e-6
