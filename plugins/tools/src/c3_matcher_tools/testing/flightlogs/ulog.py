"""A PX4 ULog of a rendered flight, written with ``pyulog`` (test and example data)."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher_tools.testing import flightlogs as fl

__all__ = ["write_ulog"]


_Topic = tuple[str, list[tuple[str, str]], dict[str, Sequence[Any]]]
"""A ULog topic: its name, (type, field) of each field, and each field's values."""


def write_ulog(
    path: Path, poses: Sequence[fl.Pose], *, flaws: Sequence[str] = (), rangefinder: bool = False
) -> Path:
    """A PX4 ULog with ``vehicle_attitude``, ``vehicle_global_position``,
    ``vehicle_gps_position`` (eph 1.5 m, 3D fix, UTC time), ``home_position`` and
    ``camera_capture`` (one per frame). ``flaws``: ``no_attitude`` (topic left out),
    ``no_trigger``, ``gnss_loss`` (the receiver reports no fix over the second frame),
    ``home_reset`` (``home_position`` first 60 s before the first frame, :data:`HOME_FIRST_M`
    higher, then again 5 s before it, as PX4 sets it again at arming), ``estimate_invalid`` and
    ``altitude_invalid`` (:func:`_ulog_validity`: the estimate states ``lat_lon_valid`` and
    ``alt_valid``, as PX4 does from 1.16 on, and marks part of itself invalid);
    ``rangefinder``: ``vehicle_local_position.dist_bottom`` (valid) states the height above
    ground, the ground 20 m higher than home (``home_position.alt``)."""
    from pyulog import ULog

    ulog = ULog(None)
    ulog._file_version = 1
    ulog._start_timestamp = int(fl.BOOT_S * 1e6) - 1_000_000
    us = [int((fl.BOOT_S + p.t_s) * 1e6) for p in poses]
    topics: list[_Topic] = []
    if "no_attitude" not in flaws:
        topics.append(_ulog_attitude(poses, us))
    estimate, receiver = _ulog_positions(poses, gnss_loss="gnss_loss" in flaws)
    if {"estimate_invalid", "altitude_invalid"} & set(flaws):
        estimate = _ulog_validity(estimate, poses, flaws)
    topics += [estimate, receiver]
    heights = _ulog_heights(poses, us, rangefinder)
    if "home_reset" in flaws:
        name, fields, home = heights[0]
        at = (us[0] - 60_000_000, us[0] - 5_000_000)
        alt = float(home["alt"][0])
        heights[0] = (name, fields, {"timestamp": at, "alt": (alt + fl.HOME_FIRST_M, alt)})
    topics += heights
    if "no_trigger" not in flaws:
        topics.append(
            (
                "camera_capture",
                [("uint64_t", "timestamp"), ("uint32_t", "seq")],
                {"timestamp": us, "seq": list(range(len(us)))},
            )
        )
    for msg_id, (name, fields, values) in enumerate(topics):
        _ulog_topic(ulog, msg_id, name, fields, values)
    path = Path(path)
    with path.open("wb") as fh:
        ulog.write_ulog(fh)
    return path


def _ulog_attitude(poses: Sequence[fl.Pose], us: list[int]) -> _Topic:
    """``vehicle_attitude``: each frame's quaternion at its time ``us`` (µs since boot)."""
    quats = [p.quaternion() for p in poses]
    return (
        "vehicle_attitude",
        [("uint64_t", "timestamp"), ("float[4]", "q")],
        {"timestamp": list(us), **{f"q[{k}]": [q[k] for q in quats] for k in range(4)}},
    )


def _ulog_positions(poses: Sequence[fl.Pose], *, gnss_loss: bool) -> list[_Topic]:
    """``vehicle_global_position`` and ``vehicle_gps_position`` along the poses (``gnss_loss``:
    no fix within 0.3 s of the second frame)."""
    dense = fl.dense_track(poses)
    dus = [int((fl.BOOT_S + d[0]) * 1e6) for d in dense]
    lost = {
        i
        for i, d in enumerate(dense)
        if gnss_loss and len(poses) > 1 and abs(d[0] - poses[1].t_s) < 0.3
    }
    estimate: _Topic = (
        "vehicle_global_position",
        [("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"), ("float", "alt")],
        {
            "timestamp": dus,
            "lat": [d[1] for d in dense],
            "lon": [d[2] for d in dense],
            "alt": [d[3] for d in dense],
        },
    )
    receiver: _Topic = (
        "vehicle_gps_position",
        [
            ("uint64_t", "timestamp"),
            ("uint64_t", "time_utc_usec"),
            ("int32_t", "lat"),
            ("int32_t", "lon"),
            ("int32_t", "alt"),
            ("float", "eph"),
            ("uint8_t", "fix_type"),
        ],
        {
            "timestamp": dus,
            "time_utc_usec": [int((fl.UTC0 + d[0]) * 1e6) for d in dense],
            "lat": [round(d[1] * 1e7) for d in dense],
            "lon": [round(d[2] * 1e7) for d in dense],
            "alt": [round(d[3] * 1e3) for d in dense],
            "eph": [99.0 if i in lost else 1.5 for i in range(len(dense))],
            "fix_type": [0 if i in lost else 3 for i in range(len(dense))],
        },
    )
    return [estimate, receiver]


def _ulog_validity(estimate: _Topic, poses: Sequence[fl.Pose], flaws: Sequence[str]) -> _Topic:
    """``estimate`` (``vehicle_global_position``) with ``lat_lon_valid`` and ``alt_valid``.
    ``estimate_invalid``: from 0.3 s before the second frame on (all along with one frame) the
    estimate drifts north at 40 m/s, GNSS rejected, and marks its position invalid (its altitude
    stays valid); ``altitude_invalid``: within 0.3 s of the second frame its altitude is 100 m
    off and marked invalid."""
    name, fields, values = estimate
    t = np.asarray(values["timestamp"], dtype=np.float64) / 1e6 - fl.BOOT_S
    lat, alt = np.asarray(values["lat"]), np.asarray(values["alt"])
    second = poses[1].t_s if len(poses) > 1 else -math.inf
    lost = t >= second - 0.3 if "estimate_invalid" in flaws else np.zeros(t.size, dtype=bool)
    drift_m = np.where(lost, (t - max(second - 0.3, t[0])) * 40.0, 0.0)
    off = np.abs(t - second) < 0.3 if "altitude_invalid" in flaws else np.zeros(t.size, dtype=bool)
    return (
        name,
        [*fields, ("bool", "lat_lon_valid"), ("bool", "alt_valid")],
        {
            **values,
            "lat": list(lat + drift_m / 111_320.0),
            "alt": list(alt + np.where(off, 100.0, 0.0)),
            "lat_lon_valid": list(~lost),
            "alt_valid": list(~off),
        },
    )


def _ulog_heights(poses: Sequence[fl.Pose], us: list[int], rangefinder: bool) -> list[_Topic]:
    """``home_position`` (its altitude the ground's, 20 m lower with a ``rangefinder``) and the
    rangefinder's ``vehicle_local_position`` at each frame's time ``us``."""
    home: _Topic = (
        "home_position",
        [("uint64_t", "timestamp"), ("float", "alt")],
        {"timestamp": [us[0]], "alt": [fl.GROUND_M - (20.0 if rangefinder else 0.0)]},
    )
    if not rangefinder:
        return [home]
    local: _Topic = (
        "vehicle_local_position",
        [
            ("uint64_t", "timestamp"),
            ("float", "dist_bottom"),
            ("bool", "dist_bottom_valid"),
            ("float", "ref_alt"),
        ],
        {
            "timestamp": us,
            "dist_bottom": [p.height_m for p in poses],
            "dist_bottom_valid": [True] * len(us),
            "ref_alt": [fl.GROUND_M - 20.0] * len(us),
        },
    )
    return [home, local]


def _ulog_topic(
    ulog: Any,
    msg_id: int,
    name: str,
    fields: list[tuple[str, str]],
    values: dict[str, Sequence[Any]],
) -> None:
    from pyulog import ULog

    spec = name + ":" + "".join(f"{t} {n};" for t, n in fields)
    ulog._message_formats[name] = ULog.MessageFormat(spec.encode(), None)
    add = ULog._MessageAddLogged(
        struct.pack("<BH", 0, msg_id) + name.encode(), None, ulog._message_formats
    )
    n = len(values["timestamp"])
    arr = np.zeros(n, dtype=add.dtype)
    for f in add.field_data:
        arr[f.field_name] = values[f.field_name]
    add.buffer = bytearray(arr.tobytes())
    ulog._data_list.append(ULog.Data(add))
