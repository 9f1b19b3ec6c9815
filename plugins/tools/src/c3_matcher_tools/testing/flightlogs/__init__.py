"""Recorded-flight logs for tests and examples, written with the libraries' own writers over a
rendered flight whose poses are known (a ``c3-flight/1`` dataset such as
``data/flights/naip_demo``): a PX4 ULog (``pyulog``, :mod:`.ulog`), a MAVLink telemetry log
(``pymavlink``, :mod:`.mavlink`), an ArduPilot DataFlash log (the documented FMT layout, read back
by ``pymavlink``, :mod:`.dataflash`), ROS 2 bags in sqlite3 and MCAP storage (``rosbags``,
:mod:`.rosbag`) and photos with EXIF/XMP (``piexif``, :mod:`.exif`).

Each log states the frames' true nadir position (``alt_m`` = ``GROUND_M`` + the height above
ground), attitude and capture time; the GNSS time of the first frame is ``UTC0``. Writers take
``flaws`` to make the bad logs the importers must refuse or flag. This module holds what every
writer shares: the poses and the times and heights they are stated in.
"""

from __future__ import annotations

import itertools
import json
import math
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from c3_matcher.camera import rotation_world_from_body
from c3_matcher.dto import Attitude

__all__ = [
    "BOOT_S",
    "GROUND_M",
    "HOME_FIRST_M",
    "UTC0",
    "Pose",
    "dense_track",
    "flight_poses",
    "pose_images",
    "pre_arm_track",
    "quaternion_wxyz",
]

GROUND_M = 500.0
"""The ground's altitude above sea level in every written log (m)."""
HOME_FIRST_M = 12.0
"""``home_reset`` (ULog, telemetry and DataFlash writers): the home first set this much above the
ground (before arming, the GNSS altitude not settled); set again at arming, at the ground's."""
UTC0 = 1_790_000_000.0
"""UTC time of the first frame (s)."""
BOOT_S = 100.0
"""Log time (s since boot) of the first frame."""


@dataclass(frozen=True)
class Pose:
    """One frame of a rendered flight: ``t_s`` from the first frame, nadir ``lat``/``lon``,
    ``height_m`` above ground, attitude (deg), ``image`` (path of the frame)."""

    t_s: float
    lat: float
    lon: float
    height_m: float
    roll: float
    pitch: float
    yaw: float
    image: Path

    @property
    def alt_m(self) -> float:
        return GROUND_M + self.height_m

    def quaternion(self) -> tuple[float, float, float, float]:
        """(w, x, y, z) of the body (FRD) to NED rotation."""
        r = rotation_world_from_body(Attitude.from_degrees(self.roll, self.pitch, self.yaw))
        return quaternion_wxyz(r)


def quaternion_wxyz(r: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of the rotation matrix ``r``."""
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return w, x, y, z


def flight_poses(dataset: Path, frames: Sequence[int]) -> list[Pose]:
    """The poses of ``frames`` of a rendered dataset (its ``frames.jsonl``)."""
    records = [json.loads(x) for x in (Path(dataset) / "frames.jsonl").read_text().splitlines()]
    out = []
    for i in frames:
        f = records[i]
        r, p, y = f["attitude_deg"]
        out.append(
            Pose(
                f["captured_at_ns"] / 1e9,
                f["pose"]["nadir_lat"],
                f["pose"]["nadir_lon"],
                float(f["height_m"]),
                r,
                p,
                y,
                Path(dataset) / f["image"],
            )
        )
    return out


def pre_arm_track(poses: Sequence[Pose]) -> list[tuple[float, float, float, float]]:
    """(t, lat, lon, alt) on the ground at the first frame's place, once a second from 30 to 11
    s before the first frame: the vehicle before arming."""
    p = poses[0]
    return [(p.t_s - 30.0 + k, p.lat, p.lon, GROUND_M) for k in range(20)]


def dense_track(
    poses: Sequence[Pose], rate_hz: float = 5.0
) -> list[tuple[float, float, float, float]]:
    """(t, lat, lon, alt) at ``rate_hz`` along the poses, straight between frames."""
    out = []
    for a, b in itertools.pairwise(poses):
        n = max(1, round((b.t_s - a.t_s) * rate_hz))
        for k in range(n):
            w = k / n
            out.append(
                (
                    a.t_s + w * (b.t_s - a.t_s),
                    a.lat + w * (b.lat - a.lat),
                    a.lon + w * (b.lon - a.lon),
                    a.alt_m + w * (b.alt_m - a.alt_m),
                )
            )
    last = poses[-1]
    out.append((last.t_s, last.lat, last.lon, last.alt_m))
    return out


def pose_images(root: Path, poses: Sequence[Pose]) -> Path:
    """``root/images`` holding each pose's image as ``IMG_0000.jpg``, ``IMG_0001.jpg``, ... in
    order: the camera's photos of a flight written from ``poses``."""
    folder = root / "images"
    folder.mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, folder / f"IMG_{i:04d}.jpg")
    return folder
