"""A ground station's MAVLink telemetry log (``.tlog``) of a rendered flight, with ``pymavlink``."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher_tools.testing import flightlogs as fl

__all__ = ["write_tlog"]


def write_tlog(
    path: Path, poses: Sequence[fl.Pose], *, flaws: Sequence[str] = (), rangefinder: bool = False
) -> Path:
    """A ground station's MAVLink telemetry log: ATTITUDE, GLOBAL_POSITION_INT, GPS_RAW_INT
    (h_acc 1.5 m) and CAMERA_FEEDBACK per frame, each prefixed by its UTC time as pymavlink
    writes it; ``rangefinder``: a DISTANCE_SENSOR at each frame, facing down, reading the range
    along the tilted body (:func:`~.dataflash.slant_range`, cm: under 655 m). ``flaws``:
    ``no_attitude``, ``no_trigger``, ``home_reset`` (GLOBAL_POSITION_INT on the ground before
    arming, its ``relative_alt`` above a home :data:`HOME_FIRST_M` higher than the ground, the
    home of the flight)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    records = _tlog_positions(poses) + _tlog_frames(poses, flaws)
    if rangefinder:
        records += [(p.t_s, _distance_sensor(p)) for p in poses]
    if "home_reset" in flaws:
        records += _tlog_positions(poses, pre_arm=True)
    records.sort(key=lambda r: r[0])
    path = Path(path)
    with path.open("wb") as fh:
        for t, msg in records:
            fh.write(struct.pack(">Q", int((fl.UTC0 + t) * 1e6)) + msg.pack(mav))
    return path


def _tlog_positions(poses: Sequence[fl.Pose], *, pre_arm: bool = False) -> list[tuple[float, Any]]:
    """(t, message) of GLOBAL_POSITION_INT and GPS_RAW_INT (3D fix, h_acc 1.5 m) along the
    poses (``pre_arm``: on the ground before arming, :func:`pre_arm_track`, the home then
    :data:`HOME_FIRST_M` higher)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    records: list[tuple[float, Any]] = []
    home = fl.GROUND_M + (fl.HOME_FIRST_M if pre_arm else 0.0)
    for t, lat, lon, alt in fl.pre_arm_track(poses) if pre_arm else fl.dense_track(poses):
        ms = int((fl.BOOT_S + t) * 1e3)
        rel = int((alt - home) * 1e3)
        lat_e7, lon_e7, alt_mm = round(lat * 1e7), round(lon * 1e7), round(alt * 1e3)
        records.append(
            (
                t,
                mavlink.MAVLink_global_position_int_message(
                    ms, lat_e7, lon_e7, alt_mm, rel, 0, 0, 0, 0
                ),
            )
        )
        utc_us = int((fl.UTC0 + t) * 1e6)
        fix = mavlink.MAVLink_gps_raw_int_message(
            utc_us, 3, lat_e7, lon_e7, alt_mm, 80, 120, 0, 0, 12, 0, 1500, 2500, 0, 0, 0
        )
        records.append((t, fix))
    return records


def _tlog_frames(poses: Sequence[fl.Pose], flaws: Sequence[str]) -> list[tuple[float, Any]]:
    """(t, message) of each frame's ATTITUDE and CAMERA_FEEDBACK (``flaws``: ``no_attitude``,
    ``no_trigger`` leave them out)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    records: list[tuple[float, Any]] = []
    for i, p in enumerate(poses):
        ms = int((fl.BOOT_S + p.t_s) * 1e3)
        if "no_attitude" not in flaws:
            roll, pitch, yaw = (math.radians(a) for a in (p.roll, p.pitch, p.yaw))
            records.append((p.t_s, mavlink.MAVLink_attitude_message(ms, roll, pitch, yaw, 0, 0, 0)))
        if "no_trigger" not in flaws:
            utc_us = int((fl.UTC0 + p.t_s) * 1e6)
            lat_e7, lon_e7 = round(p.lat * 1e7), round(p.lon * 1e7)
            feedback = mavlink.MAVLink_camera_feedback_message(
                utc_us, 1, 0, i, lat_e7, lon_e7, p.alt_m, p.height_m, p.roll, p.pitch, p.yaw, 4.5, 0
            )
            records.append((p.t_s, feedback))
    return records


def _distance_sensor(p: fl.Pose) -> Any:
    """The DISTANCE_SENSOR of a downward rangefinder (0.2 to 655 m) at pose ``p``, its range
    along the tilted body."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from c3_matcher_tools.testing.flightlogs.dataflash import slant_range

    ms = int((fl.BOOT_S + p.t_s) * 1e3)
    down = mavlink.MAV_SENSOR_ROTATION_PITCH_270
    cm = round(slant_range(p) * 100)
    return mavlink.MAVLink_distance_sensor_message(ms, 20, 65_500, cm, 0, 0, down, 0)
