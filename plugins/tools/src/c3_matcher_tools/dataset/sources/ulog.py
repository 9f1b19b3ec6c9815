"""PX4 ULog flight logs (``.ulg``), read with ``pyulog`` (the tools' ``logs`` extra).

Topics used (instance 0): attitude from ``vehicle_attitude.q`` (body FRD to NED, w x y z;
without it each frame is imported level, its yaw from the GNSS course, and marked);
position from ``vehicle_global_position`` (lat, lon, alt AMSL) when logged, else from the
receiver, as also where the estimate marks itself invalid (``lat_lon_valid`` / ``alt_valid``
false, PX4 1.16 on); the receiver's fix, stated horizontal accuracy ``eph`` and UTC time from
``vehicle_gps_position`` (or ``sensor_gps``; old ``lat``/``lon`` in 1e-7 deg and ``alt`` in mm,
or new ``latitude_deg``/``longitude_deg``/``altitude_msl_m``); height above ground from
``vehicle_local_position.dist_bottom`` where ``dist_bottom_valid``; the ground's altitude from
``home_position.alt`` (each home as it was set: PX4 sets it again at arming) else
``vehicle_local_position.ref_alt``; camera trigger times from
``camera_capture`` / ``camera_trigger``. Times: the log's ``timestamp`` (microseconds since
boot) in seconds.

Besides pyulog, the reader walks the file's message headers (each its size and type, as the
ULog format lays them out) to say what pyulog does not: definitions too damaged to read any topic
(refused as such), and a log that ends mid-message (cut short: pyulog keeps what came before and
says nothing).
"""

from __future__ import annotations

import io
import math
import mmap
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.quiet import quiet
from c3_matcher_tools.dataset.sources.track import (
    MIN_QUATERNION_NORM,
    LogTrack,
    Series,
    attitude_from_matrix,
    cut_short,
    home_series,
    logs_library,
    quaternion_matrix,
)

__all__ = ["read_ulog"]

KIND = "PX4 ULog"
TOPICS = (
    "vehicle_attitude",
    "vehicle_global_position",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_local_position",
    "home_position",
    "camera_capture",
    "camera_trigger",
)


MAGIC = b"ULog\x01\x12\x35"
"""A ULog's first bytes."""
HEADER_BYTES = 16
"""A ULog's file header (:data:`MAGIC`, version, start time); its messages follow."""
MESSAGE_TYPES = frozenset(b"BFIMPQARDLCSO")
"""The message types the ULog format defines (the third byte of each message's header)."""
DEFINITION_TYPES = frozenset(b"BFIMPQ")
"""Those of the definitions section: it ends at the first message of another type."""


@dataclass(frozen=True)
class _Layout:
    """What a walk of a ULog's message headers found. ``definitions_damaged_at``: the byte where
    the definitions section stops being readable (a header of no ULog type, or the data with no
    format definition before it), None when it reads; ``cut_at``: the byte where the last
    message starts when it runs past the end of the file (the log ends mid-message), None when
    the file ends where a message does or the walk met damage first (pyulog says that)."""

    definitions_damaged_at: int | None = None
    cut_at: int | None = None


def _layout(path: Path) -> _Layout:
    """Walk ``path``'s message headers (3 bytes: size, type) from the file header on; nothing
    found when it is no ULog or cannot be read (pyulog then says why)."""
    try:
        with path.open("rb") as fh:
            if path.stat().st_size <= HEADER_BYTES or fh.read(len(MAGIC)) != MAGIC:
                return _Layout()
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return _walk(data)
    except (OSError, ValueError):
        return _Layout()


def _walk(data: mmap.mmap) -> _Layout:
    end, at, formats, definitions = len(data), HEADER_BYTES, 0, True
    while at < end:
        if end - at < 3:  # a header cut short
            return _Layout(cut_at=at)
        size, kind = struct.unpack_from("<HB", data, at)
        if kind not in MESSAGE_TYPES or size == 0:  # damage: pyulog skips it, and says so
            return _Layout(definitions_damaged_at=at if definitions else None)
        if definitions and kind not in DEFINITION_TYPES:
            definitions = False
            if not formats:
                return _Layout(definitions_damaged_at=at)
        formats += kind == ord("F")
        if at + 3 + size > end:
            return _Layout(cut_at=at)
        at += 3 + size
    return _Layout()


def _load(path: Path) -> tuple[Any, str | None, _Layout]:
    """The parsed log, what pyulog said when it found the log damaged or truncated (it reads up
    to the damage; several warnings in one, the first and their count) and the file's
    :class:`_Layout`; pyulog's own prints (on stdout, where ``--json`` output goes) are kept
    from the terminal. A log whose definitions are too damaged to read any topic is refused."""
    pyulog = logs_library("pyulog", path, "a ULog")
    if not path.is_file():
        raise InvalidInputError(str(path), "no such file")
    layout = _layout(path)
    said = io.StringIO()
    try:
        with quiet(said):
            ulog = pyulog.ULog(str(path), list(TOPICS))
    except Exception as exc:  # pyulog raises several types on a damaged file
        if layout.definitions_damaged_at is not None:
            raise InvalidInputError(str(path), _damaged_definitions(layout)) from None
        raise InvalidInputError(str(path), f"not a readable PX4 ULog: {exc}") from None
    if layout.definitions_damaged_at is not None and not ulog.data_list:
        raise InvalidInputError(str(path), _damaged_definitions(layout))
    warnings = [line.strip() for line in said.getvalue().splitlines() if line.strip()]
    more = f" (+{len(warnings) - 1} more warnings)" if len(warnings) > 1 else ""
    damage = (warnings[0] + more) if warnings else "file corruption detected"
    return ulog, damage if ulog.file_corruption else None, layout


def _damaged_definitions(layout: _Layout) -> str:
    return (
        "not a readable PX4 ULog: its message definitions (the formats of its topics) are "
        f"damaged from byte {layout.definitions_damaged_at} on, so none of its topics can be read"
    )


def _topic(ulog: Any, name: str, source: str) -> dict[str, np.ndarray] | None:
    """Instance 0 of topic ``name``, None when not logged or empty; refused when it lacks its
    ``timestamp`` (a damaged format definition)."""
    try:
        data = ulog.get_dataset(name, 0).data
    except (KeyError, IndexError, ValueError):
        return None
    return data if len(_required(data, name, "timestamp", source)) else None


def _field(data: dict[str, np.ndarray], *names: str, scale: float = 1.0) -> np.ndarray | None:
    for n in names:
        if n in data:
            return np.asarray(data[n], dtype=np.float64) * scale
    return None


def _required(data: dict[str, np.ndarray], topic: str, name: str, source: str) -> np.ndarray:
    """Field ``name`` of ``topic``'s ``data``; refused naming both when the topic lacks it (its
    format definition damaged, or not PX4's)."""
    got = _field(data, name)
    if got is None:
        raise InvalidInputError(
            source, f"{topic} lacks its field {name!r} (a damaged format definition?)"
        )
    return got


def _new_or_old(data: dict[str, np.ndarray], new: str, old: str, scale: float) -> np.ndarray | None:
    """A receiver field by its current name (SI units), else by its older integer one."""
    return _field(data, new) if new in data else _field(data, old, scale=scale)


def _attitude(ulog: Any, source: str) -> Series | None:
    """``vehicle_attitude.q`` as roll, pitch, yaw (deg); None when the log has no such topic
    or none of its quaternions states an orientation (about zero norm: such a sample is
    skipped)."""
    att = _topic(ulog, "vehicle_attitude", source)
    if att is None:
        return None
    t = att["timestamp"].astype(np.float64) / 1e6
    q = np.stack([_required(att, "vehicle_attitude", f"q[{k}]", source) for k in range(4)], 1)
    stated = np.linalg.norm(q.astype(np.float64), axis=1) >= MIN_QUATERNION_NORM
    if not stated.any():
        return None
    angles = [
        attitude_from_matrix(quaternion_matrix(*map(float, qi))) if ok else (math.nan,) * 3
        for qi, ok in zip(q, stated, strict=True)
    ]
    return Series.build("vehicle_attitude", t, angles, (2,), source=source)


def _receiver(ulog: Any, source: str) -> tuple[Series | None, float | None]:
    """The receiver's fix (lat, lon, alt, eph, fix type; no position without a fix) and the
    log's UTC offset, from ``vehicle_gps_position`` or ``sensor_gps``."""
    gps = _topic(ulog, "vehicle_gps_position", source) or _topic(ulog, "sensor_gps", source)
    if gps is None:
        return None, None
    gnss = None
    lat = _new_or_old(gps, "latitude_deg", "lat", 1e-7)
    lon = _new_or_old(gps, "longitude_deg", "lon", 1e-7)
    alt = _new_or_old(gps, "altitude_msl_m", "alt", 1e-3)
    eph = _field(gps, "eph")
    fix = _field(gps, "fix_type")
    tg = gps["timestamp"].astype(np.float64) / 1e6
    if lat is not None and lon is not None and alt is not None:
        n = tg.size
        cols = np.stack(
            [
                lat,
                lon,
                alt,
                eph if eph is not None else np.full(n, math.nan),
                fix if fix is not None else np.full(n, 3.0),
            ],
            axis=1,
        )
        good = (cols[:, 4] >= 2) & ((cols[:, 0] != 0) | (cols[:, 1] != 0))
        cols[~good, :3] = np.nan  # no fix: no position, the frame is flagged degraded
        gnss = Series.build("vehicle_gps_position", tg, cols, source=source)
    utc = _field(gps, "time_utc_usec")
    if utc is None or not np.any(utc > 0):
        return gnss, None
    k = int(np.flatnonzero(utc > 0)[0])
    return gnss, float(utc[k] / 1e6 - tg[k])


def _global_position(ulog: Any, source: str) -> tuple[Series | None, list[str]]:
    """The estimator's lat, lon, alt and notes on what it marked invalid. PX4 1.16 on states
    ``lat_lon_valid`` and ``alt_valid`` (once the estimator has lost its reference, GNSS
    rejected, its position drifts on and is marked invalid): a sample marked invalid keeps its
    time without its position (or altitude), so that a frame beside it takes the receiver's as
    where the log has no estimate, never one interpolated across it. A log without those fields
    is read as it is. None when no sample has a valid position."""
    glob = _topic(ulog, "vehicle_global_position", source)
    if glob is None:
        return None, []
    tp = glob["timestamp"].astype(np.float64) / 1e6
    cols = np.stack(
        [_required(glob, "vehicle_global_position", k, source) for k in ("lat", "lon", "alt")],
        axis=1,
    )
    lat_lon_ok, alt_ok = _field(glob, "lat_lon_valid"), _field(glob, "alt_valid")
    lost = np.zeros(tp.size, dtype=bool) if lat_lon_ok is None else lat_lon_ok == 0
    no_alt = np.zeros(tp.size, dtype=bool) if alt_ok is None else (alt_ok == 0) & ~lost
    notes = [
        f"vehicle_global_position marks {what} invalid ({flag} false) in {int(mask.sum())} of "
        f"its {tp.size} samples ({_stretches(tp, mask)}): {then}"
        for mask, what, flag, then in (
            (lost, "its position", "lat_lon_valid", "frames there take the receiver's position "
             "(vehicle_gps_position) where it has a fix"),
            (no_alt, "its altitude", "alt_valid", "frames there take the receiver's altitude"),
        )
        if mask.any()
    ]  # fmt: skip
    if lost.all():
        return None, notes
    cols[lost] = np.nan
    cols[no_alt, 2] = np.nan
    marked = np.where(lost, 0.0, np.nan)[:, None]  # keeps a sample without a position
    series = Series.build("vehicle_global_position", tp, np.hstack([cols, marked]), source=source)
    return replace(series, values=series.values[:, :3]), notes


def _stretches(t: np.ndarray, mask: np.ndarray) -> str:
    """The stretches of log time ``t`` (s) where ``mask`` holds, the first three."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    runs = [f"{t[a]:.1f}-{t[b - 1]:.1f} s" for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return ", ".join(runs[:3]) + (f" and {len(runs) - 3} more" if len(runs) > 3 else "")


def _ground(ulog: Any, source: str) -> tuple[Series | None, Series | None, str | None]:
    """The rangefinder's valid heights above ground, the home altitudes as they were set over
    the log (:func:`home_series`: ``home_position.alt`` where ``valid_alt``, else the estimator's
    reference ``vehicle_local_position.ref_alt`` where set) and a note when the home was set
    again at another altitude."""
    local = _topic(ulog, "vehicle_local_position", source)
    height = None
    home_at: tuple[str, np.ndarray, np.ndarray] | None = None
    if local is not None:
        tl = local["timestamp"].astype(np.float64) / 1e6
        dist = _field(local, "dist_bottom")
        valid = _field(local, "dist_bottom_valid")
        if dist is not None and valid is not None and np.any(valid > 0):
            keep = valid > 0
            height = Series.build(
                "vehicle_local_position.dist_bottom", tl[keep], dist[keep, None], source=source
            )
        ref = _field(local, "ref_alt")
        if ref is not None and np.any(ref != 0):
            home_at = ("vehicle_local_position.ref_alt", tl[ref != 0], ref[ref != 0])
    home = _topic(ulog, "home_position", source)
    alt = None if home is None else _field(home, "alt")
    if home is not None and alt is not None:
        valid_alt = _field(home, "valid_alt")
        keep = valid_alt > 0 if valid_alt is not None else np.ones(alt.size, dtype=bool)
        if keep.any():
            th = home["timestamp"].astype(np.float64) / 1e6
            home_at = ("home_position.alt", th[keep], alt[keep])
    if home_at is None:
        return height, None, None
    return (height, *home_series(*home_at, source=source))


def _triggers(ulog: Any, notes: list[str], source: str) -> np.ndarray | None:
    for topic in ("camera_capture", "camera_trigger"):
        cam = _topic(ulog, topic, source)
        if cam is not None:
            triggers = np.sort(cam["timestamp"].astype(np.float64) / 1e6)
            notes.append(f"{triggers.size} camera trigger(s) from {topic}")
            return triggers
    return None


def read_ulog(path: Path) -> LogTrack:
    """The track of a PX4 ULog (see the module docstring); raises InvalidInputError naming
    the file and the missing topics when it holds no position. A log without
    ``vehicle_attitude`` is read, and said so in its notes: each frame is then imported level
    with the yaw of its GNSS course and marked ``attitude_assumed``."""
    path = Path(path)
    ulog, said, layout = _load(path)
    source = str(path)
    notes = [f"the log is damaged or truncated ({said}); read up to the damage"] if said else []
    cut = None if layout.cut_at is None else cut_short(layout.cut_at, path.stat().st_size)
    if cut:
        notes.append(f"the log {cut}; the samples before it are kept")
    damage = "; ".join(x for x in (said, cut and f"it {cut}") if x) or None
    damaged = f"the log is damaged or truncated ({damage}); " if damage else ""
    attitude = _attitude(ulog, source)
    if attitude is None:
        notes.append(
            "no vehicle_attitude topic: every frame's attitude assumed level, its yaw from the "
            "GNSS course (frames marked attitude_assumed)"
        )
    gnss, utc_offset = _receiver(ulog, source)
    position, invalid = _global_position(ulog, source)
    notes += invalid
    without = "no vehicle_global_position"
    if position is None and invalid:
        without = "vehicle_global_position marks every position invalid"
    if position is None and gnss is not None:
        notes.append(f"{without}: positions from vehicle_gps_position")
    if position is None and gnss is None:
        nor = " and no" if invalid else " nor"
        raise InvalidInputError(
            source, f"{damaged}{without}{nor} vehicle_gps_position: the log holds no position"
        )
    height, home, home_note = _ground(ulog, source)
    notes += [home_note] if home_note else []
    triggers = _triggers(ulog, notes, source)
    return LogTrack(
        source=source,
        kind=KIND,
        attitude=attitude,
        position=position,
        gnss=gnss,
        height=height,
        triggers_s=triggers,
        home=home,
        utc_offset_s=utc_offset,
        notes=tuple(notes),
        damage=damage,
    )
