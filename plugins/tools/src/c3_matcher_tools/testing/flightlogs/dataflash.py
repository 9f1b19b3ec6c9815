"""An ArduPilot DataFlash log (``.bin``) of a rendered flight, in the documented FMT layout."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from c3_matcher_tools.testing import flightlogs as fl

__all__ = ["slant_range", "write_dataflash"]

_DF_HEAD = b"\xa3\x95"
_DF_FORMATS = {
    # name: (type id, struct format chars, columns)
    "ATT": (1, "Qfff", "TimeUS,Roll,Pitch,Yaw"),
    "POS": (2, "QLLff", "TimeUS,Lat,Lng,Alt,RelHomeAlt"),
    "GPS": (3, "QBIHLLf", "TimeUS,Status,GMS,GWk,Lat,Lng,Alt"),
    "GPA": (4, "Qf", "TimeUS,HAcc"),
    "CAM": (5, "QH", "TimeUS,Img"),
}
_DF_RFND = (6, "QBfBB", "TimeUS,Instance,Dist,Stat,Orient")
"""The RFND format, in a log written with a rangefinder alone (so that the other logs keep their
bytes)."""
_DF_STRUCT = {"Q": "Q", "f": "f", "L": "i", "B": "B", "I": "I", "H": "H"}


def write_dataflash(
    path: Path, poses: Sequence[fl.Pose], *, flaws: Sequence[str] = (), rangefinder: bool = False
) -> Path:
    """An ArduPilot DataFlash log in the documented binary layout (FMT messages, then ATT, POS,
    GPS with GNSS week time, GPA and CAM; ``rangefinder``: an RFND at each frame, a downward
    rangefinder's good reading of :func:`slant_range`); ``flaws``: ``no_attitude``, ``no_trigger``,
    ``time_jump`` (the middle frame's ATT stamped 5 s before the frame before it), ``home_reset``
    (POS on the ground before arming, its ``RelHomeAlt`` above a home :data:`HOME_FIRST_M`
    higher than the ground, the home of the flight)."""
    formats = {**_DF_FORMATS, **({"RFND": _DF_RFND} if rangefinder else {})}
    out = bytearray(_fmt_header(formats))

    def msg(name: str, *values: Any) -> tuple[int, bytes]:
        type_id, fmt, _ = formats[name]
        body = struct.pack("<" + "".join(_DF_STRUCT[c] for c in fmt), *values)
        return values[0], _DF_HEAD + bytes([type_id]) + body

    gps_epoch = 315_964_800.0  # 1980-01-06 UTC
    leap = 18.0
    items: list[tuple[int, bytes]] = []
    if "home_reset" in flaws:  # on the ground before arming, the home then higher
        items += [msg("POS", *values) for values in _pre_arm_positions(poses)]
    for t, lat, lon, alt in fl.dense_track(poses):
        tus = int((fl.BOOT_S + t) * 1e6)
        gps_s = fl.UTC0 + t - gps_epoch + leap
        week, ms = int(gps_s // 604800), round((gps_s % 604800) * 1e3)
        items.append(msg("POS", tus, round(lat * 1e7), round(lon * 1e7), alt, alt - fl.GROUND_M))
        items.append(msg("GPS", tus, 3, ms, week, round(lat * 1e7), round(lon * 1e7), alt))
        items.append(msg("GPA", tus, 1.5))
    for i, p in enumerate(poses):
        tus = int((fl.BOOT_S + p.t_s) * 1e6)
        if "no_attitude" not in flaws:
            att = msg("ATT", tus, p.roll, p.pitch, p.yaw % 360.0)
            if "time_jump" in flaws and i == len(poses) // 2:
                back = int((fl.BOOT_S + poses[i - 1].t_s - 5.0) * 1e6)
                att = (tus, msg("ATT", back, p.roll, p.pitch, p.yaw % 360.0)[1])
            items.append(att)
        if "no_trigger" not in flaws:
            items.append(msg("CAM", tus, i))
        if rangefinder:
            items.append(msg("RFND", tus, 0, slant_range(p), 4, 25))
    items.sort(key=lambda x: x[0])
    for _, data in items:
        out += data
    path = Path(path)
    path.write_bytes(bytes(out))
    return path


def _fmt_header(formats: dict[str, tuple[int, str, str]]) -> bytes:
    """The log's FMT messages: FMT's own, then one of each of ``formats``."""

    def fmt_message(type_id: int, name: str, fmt: str, cols: str) -> bytes:
        length = 3 + struct.calcsize("<" + "".join(_DF_STRUCT[c] for c in fmt))
        return (
            _DF_HEAD
            + bytes([128])
            + struct.pack(
                "<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), cols.encode()
            )
        )

    columns = b"Type,Length,Name,Format,Columns"
    head = _DF_HEAD + bytes([128]) + struct.pack("<BB4s16s64s", 128, 89, b"FMT", b"BBnNZ", columns)
    return head + b"".join(fmt_message(t, name, f, c) for name, (t, f, c) in formats.items())


def slant_range(p: fl.Pose) -> float:
    """What a rangefinder fixed to the body, facing down, reads over flat ground at pose ``p``:
    the range along the tilted body's down axis, height / (cos roll cos pitch)."""
    tilt = math.cos(math.radians(p.roll)) * math.cos(math.radians(p.pitch))
    return p.height_m / tilt


def _pre_arm_positions(poses: Sequence[fl.Pose]) -> list[tuple[Any, ...]]:
    """POS values on the ground before arming (:func:`pre_arm_track`), ``RelHomeAlt`` above a
    home :data:`HOME_FIRST_M` higher than the ground."""
    home = fl.GROUND_M + fl.HOME_FIRST_M
    return [
        (int((fl.BOOT_S + t) * 1e6), round(lat * 1e7), round(lon * 1e7), alt, alt - home)
        for t, lat, lon, alt in fl.pre_arm_track(poses)
    ]
