"""ArduPilot logs read with ``pymavlink`` (the tools' ``logs`` extra): DataFlash logs written on
the vehicle (``.bin``) and MAVLink telemetry logs recorded by a ground station (``.tlog``).

Messages used (DataFlash / MAVLink): attitude ``ATT`` (Roll, Pitch, Yaw, deg) / ``ATTITUDE``
(rad; without either, each frame is imported level, its yaw from the GNSS course, and marked);
position ``POS`` (Lat, Lng, Alt above sea level; ``RelHomeAlt`` gives the home altitude) /
``GLOBAL_POSITION_INT`` (1e-7 deg, mm; ``relative_alt``; not at 0, 0), the home altitude at
each sample (ArduPilot sets it again at arming); the receiver ``GPS``
(Status = fix type, horizontal accuracy from ``GPA.HAcc``; instance 0, the first receiver) /
``GPS_RAW_INT`` (fix_type, ``h_acc`` mm); height above ground from the first downward
rangefinder, ``RFND.Dist`` / ``DISTANCE_SENSOR.current_distance`` (cm; see :func:`_ranges` and
:func:`_heights`): the range along the tilted body, made vertical at each frame with its
attitude (:attr:`~.track.LogTrack.height_along_body`); camera triggers, one per photo, of the
first of :data:`TRIGGERS` logged (a photo's MAVLink message received again, over a second
link, once: :func:`_shutter`).
A telemetry log holding several MAVLink systems (vehicles on one link) is read for the camera
vehicle's alone, or the one given (:func:`~.mavlink_systems.camera_system`). Times: the time
pymavlink gives each message (UTC seconds from the GNSS week time in a DataFlash log with a fix,
the ground station's clock in a telemetry log).
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.mavlink_systems import Row, System, camera_system, photo
from c3_matcher_tools.dataset.sources.quiet import quiet
from c3_matcher_tools.dataset.sources.track import (
    LogTrack,
    Series,
    cut_short,
    home_series,
    logs_library,
)

__all__ = ["read_mavlink"]

DATAFLASH_MAGIC = b"\xa3\x95\x80"
"""A DataFlash log's first bytes: the message header and the FMT message's type."""
TYPES = [
    "ATT",
    "ATTITUDE",
    "POS",
    "GLOBAL_POSITION_INT",
    "GPS",
    "GPA",
    "GPS_RAW_INT",
    "RFND",
    "DISTANCE_SENSOR",
    "CAM",
    "TRIG",
    "CAMERA_FEEDBACK",
    "CAMERA_TRIGGER",
]


def _open(path: Path, chatter: io.StringIO) -> Any:
    """The open log: a binary DataFlash log by its content (whatever its name), a text one
    (``.log``) or a MAVLink ``.tlog`` by its name."""
    mavutil = logs_library("pymavlink.mavutil", path, "an ArduPilot log")
    dfreader = logs_library("pymavlink.DFReader", path, "an ArduPilot log")
    if not path.is_file():
        raise InvalidInputError(str(path), "no such file")
    suffix = path.suffix.lower()
    binary = False
    if suffix != ".tlog":
        with path.open("rb") as fh:
            head = fh.read(4)
        binary = head[:3] == DATAFLASH_MAGIC
        text = suffix == ".log" and head == b"FMT,"  # a text DataFlash log's first line
        if not binary and not text:
            raise InvalidInputError(
                str(path), "not an ArduPilot DataFlash log: it does not start with a FMT message"
            )
    try:
        with quiet(chatter):  # the DataFlash index prints damaged headers
            if binary:  # by its content: a binary log named .log is binary all the same
                return dfreader.DFReader_binary(str(path), zero_time_base=False)
            return mavutil.mavlink_connection(str(path), robust_parsing=True)
    except Exception as exc:
        raise InvalidInputError(str(path), f"not a readable ArduPilot log: {exc}") from None


def _cut_at(log: Any, path: Path) -> str | None:
    """How a DataFlash log ends mid-message (:func:`cut_short`). A binary one, from pymavlink's
    index of where each message starts: its last message runs past the end of the file, or a
    header's first bytes follow it. A text one: its last line has no newline (pymavlink reads a
    line once its newline is there, so that line is lost). None when it ends where a message
    does (or is a telemetry log: see :func:`_packet_cut`)."""
    from pymavlink.DFReader import DFReader_binary, DFReader_text

    if isinstance(log, DFReader_text):
        return _line_cut(path)
    if not isinstance(log, DFReader_binary):
        return None
    starts = [(at[-1], kind) for kind, at in enumerate(log.offsets) if at]
    if not starts:
        return None
    at, kind = max(starts)
    fmt, size = log.formats.get(kind), log.data_len
    if fmt is None:
        return None
    if at + fmt.len > size:
        return cut_short(at, size, f"a {fmt.name} message")
    with path.open("rb") as fh:  # after the last whole message: a header's first bytes?
        fh.seek(at + fmt.len)
        tail = fh.read(3)
    if tail and len(tail) < 3 and DATAFLASH_MAGIC[:2].startswith(tail):
        return cut_short(at + fmt.len, size, "a message header")
    return None


def _line_cut(path: Path) -> str | None:
    """How a text DataFlash log whose last line has no newline ends: in that line (named by its
    message), from the byte after the last newline; None when it ends with a newline."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        fh.seek(max(size - 1, 0))
        if fh.read(1) in (b"", b"\n"):
            return None
        start = size
        while start > 0:  # back to the byte after the last newline, 4 KiB at a time
            back = max(start - 4096, 0)
            fh.seek(back)
            at = fh.read(start - back).rfind(b"\n")
            if at >= 0:
                start = back + at + 1
                break
            start = back
        fh.seek(start)
        name = fh.read(17).split(b",")[0].strip()
    named = name.isalnum() and len(name) <= 16  # a message's name, not bytes of damage
    return cut_short(start, size, f"a {name.decode()} line" if named else "a line")


def _packet_cut(log: Any, path: Path) -> str | None:
    """How a MAVLink telemetry log, read to its end, ends mid-packet (:func:`cut_short`): its
    parser still holds the first bytes of a packet no byte completed (bytes that start no packet
    are dropped as they are read); None when it ends where a packet does (or is no telemetry
    log)."""
    from pymavlink.mavutil import mavlogfile

    left = log.mav.buf_len() if isinstance(log, mavlogfile) else 0
    if not left:
        return None
    size = path.stat().st_size
    return cut_short(size - left, size, "a MAVLink packet")


DOWNWARD = 25
"""MAV_SENSOR_ROTATION_PITCH_270: a rangefinder facing down, the only one that measures the
height above ground (``DISTANCE_SENSOR.orientation``, ``RFND.Orient``)."""
RANGE_GOOD = 4
"""``RFND.Stat`` of a good reading (ArduPilot's RangeFinder status Good)."""


TRIGGERS = ("CAM", "CAMERA_FEEDBACK", "TRIG", "CAMERA_TRIGGER")
"""The camera messages, the one read first: ``CAM`` / ``CAMERA_FEEDBACK`` (ArduPilot: the shutter's
feedback, or the trigger when no feedback pin is set) before ``TRIG`` / ``CAMERA_TRIGGER`` (the
trigger, logged beside ``CAM`` for the same photo when a feedback pin is set; PX4's own)."""


def _first_instance(m: Any, column: str) -> bool:
    """Whether a DataFlash message is of instance 0 by its ``column`` (``I`` of GPS / GPA);
    a format without that column has one instance."""
    return int(getattr(m, column, 0)) == 0


def _ranges(m: Any, t: float) -> list[Row]:
    """A rangefinder message's downward readings, each (t, [distance m, instance, whether it is
    a height]): ``DISTANCE_SENSOR`` (``id``; cm, within [min_distance, max_distance): a reading
    out of range is none) or ``RFND``: one rangefinder a message (``Instance``; good by
    ``Stat``), or in the format of ArduPilot 3.5-3.6, ``Dist1``, ``Orient1``, ``Dist2``,
    ``Orient2`` (rangefinders 0 and 1; before 3.5 without the orientations). A format without
    ``Stat`` is read without that check, its zero readings (no reading) left out; one without
    an orientation is taken as facing down."""
    if m.get_type() == "DISTANCE_SENSOR":
        if m.orientation != DOWNWARD:
            return []
        good = m.min_distance <= m.current_distance < m.max_distance
        return [(t, [m.current_distance * 1e-2, float(m.id), float(good)])]
    if hasattr(m, "Dist"):
        readings = [(m.Dist, getattr(m, "Instance", 0), getattr(m, "Orient", DOWNWARD))]
    elif hasattr(m, "Dist1"):  # two rangefinders a message
        readings = [(m.Dist1, 0, getattr(m, "Orient1", DOWNWARD))]
        if hasattr(m, "Dist2"):
            readings.append((m.Dist2, 1, getattr(m, "Orient2", DOWNWARD)))
    else:  # neither layout: the type is ignored, and said so (see _take)
        raise AttributeError("Dist")
    status = getattr(m, "Stat", None)
    return [
        (t, [float(d), float(k), float(d > 0 if status is None else status == RANGE_GOOD)])
        for d, k, orient in readings
        if orient == DOWNWARD
    ]


def _heights(readings: list[Row]) -> list[Row]:
    """The first downward rangefinder's good readings (ArduPilot's height above ground comes
    from the first rangefinder that faces down, whatever its number)."""
    if not readings:
        return []
    first = min(v[1] for _, v in readings)
    return [(t, v[:1]) for t, v in readings if v[1] == first and v[2]]


def _fixed_position(m: Any) -> bool:
    """Whether a GLOBAL_POSITION_INT states a position: ArduPilot sends latitude and longitude
    0 before its estimator has an origin (a place no flight of this product is at)."""
    return bool(m.lat != 0 or m.lon != 0)


WANTED: dict[str, Callable[[Any], bool]] = {
    "GPS": lambda m: _first_instance(m, "I"),
    "GPA": lambda m: _first_instance(m, "I"),
    "GLOBAL_POSITION_INT": _fixed_position,
}
"""Per message type, which of its messages are read (every one of a type not named)."""


def _position(
    rows: dict[str, list[Row]],
    home: list[Row],
    t: float,
    lat: float,
    lon: float,
    alt: float,
    home_alt: float,
) -> None:
    rows["pos"].append((t, [lat, lon, alt]))
    home.append((t, [home_alt]))


def _handlers(system: System) -> dict[str, Callable[[Any, float], None]]:
    """Per message type, what its message adds to ``system``."""
    rows, home, hacc = system.rows, system.home, system.hacc
    return {
        "ATT": lambda m, t: rows["att"].append((t, [m.Roll, m.Pitch, m.Yaw])),
        "ATTITUDE": lambda m, t: rows["att"].append(
            (t, [math.degrees(m.roll), math.degrees(m.pitch), math.degrees(m.yaw)])
        ),
        "POS": lambda m, t: _position(
            rows, home, t, m.Lat, m.Lng, m.Alt, m.Alt - getattr(m, "RelHomeAlt", math.nan)
        ),
        "GLOBAL_POSITION_INT": lambda m, t: _position(
            rows, home, t, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, (m.alt - m.relative_alt) * 1e-3
        ),
        "GPS": lambda m, t: rows["gps"].append((t, [m.Lat, m.Lng, m.Alt, math.nan, m.Status])),
        "GPA": lambda m, t: hacc.append((t, float(m.HAcc))),
        "GPS_RAW_INT": lambda m, t: rows["gps"].append(
            (
                t,
                [
                    m.lat * 1e-7,
                    m.lon * 1e-7,
                    m.alt * 1e-3,
                    getattr(m, "h_acc", 0) * 1e-3 or math.nan,
                    m.fix_type,
                ],
            )
        ),
        "RFND": lambda m, t: rows["rng"].extend(_ranges(m, t)),
        "DISTANCE_SENSOR": lambda m, t: rows["rng"].extend(_ranges(m, t)),
        **{name: lambda m, t: _shutter(system, m, t) for name in TRIGGERS},
    }


def _shutter(system: System, m: Any, t: float) -> None:
    """A camera message into ``system``'s triggers, unless it tells of a photo one before it
    did (:func:`~.mavlink_systems.photo`): then it is counted as repeated, and dropped."""
    name, shot = m.get_type(), photo(m)
    if shot is not None and shot in system.photos:
        system.repeated[name] = system.repeated.get(name, 0) + 1
        return
    if shot is not None:
        system.photos.add(shot)
    system.rows["trig"].append((t, [TRIGGERS.index(name)]))


def _read(log: Any, source: str, kind: str, chatter: io.StringIO) -> dict[int, System]:
    """Every message of :data:`TYPES` (those :data:`WANTED`) through its handler, by the
    MAVLink system that sent it (0: a DataFlash log's, which names none)."""
    systems: dict[int, tuple[System, dict[str, Callable[[Any, float], None]]]] = {}
    try:
        with quiet(chatter):
            while (msg := log.recv_match(type=TYPES)) is not None:
                sent_by = getattr(msg, "get_srcSystem", None)
                number = int(sent_by()) if sent_by is not None else 0
                if number not in systems:
                    system = System()
                    systems[number] = (system, _handlers(system))
                _take(msg, *systems[number])
    except Exception as exc:
        raise InvalidInputError(source, f"unreadable {kind}: {exc}") from None
    finally:
        log.close()
    if not systems:
        damaged = chatter.getvalue().count("bad header")
        raise InvalidInputError(
            source,
            f"not a readable {kind}: no ATT, POS, GPS or camera message found"
            + (f" ({damaged} damaged headers skipped)" if damaged else ""),
        )
    return {number: system for number, (system, _) in systems.items()}


def _take(msg: Any, system: System, handlers: dict[str, Callable[[Any, float], None]]) -> None:
    """``msg`` through its handler into ``system`` (when :data:`WANTED`). A message whose format
    lacks a column read (a layout of another ArduPilot version) is ignored, and every later one
    of its type: the column is named in the notes, and the log read without them."""
    name = msg.get_type()
    system.seen.add(name)
    if name in system.ignored:
        return
    try:
        if name not in WANTED or WANTED[name](msg):
            handlers[name](msg, float(msg._timestamp))
    except AttributeError as exc:  # each reads its columns before it adds a sample
        system.ignored[name] = str(exc.name or exc)


def _receiver(gnss: Series | None, hacc: list[tuple[float, float]]) -> Series | None:
    """The receiver's fixes with ``GPA.HAcc`` as their accuracy; no position without a fix."""
    if gnss is None:
        return None
    values = gnss.values.copy()
    if hacc:
        ht = np.array([t for t, _ in hacc])
        hv = np.array([v for _, v in hacc])
        values[:, 3] = hv[np.clip(np.searchsorted(ht, gnss.t_s), 0, ht.size - 1)]
    values[values[:, 4] < 2, :3] = math.nan
    return Series(gnss.name, gnss.t_s, values)


def read_mavlink(path: Path, system: int | None = None) -> LogTrack:
    """The track of a DataFlash ``.bin`` / ``.log`` or MAVLink ``.tlog`` (see the module
    docstring), read for MAVLink system ``system`` when given (a telemetry log's alone);
    raises InvalidInputError naming the file and the missing messages when it holds no
    position. A log without attitude is read, and said so in its notes: each frame is then
    imported level with the yaw of its GNSS course and marked ``attitude_assumed``."""
    path = Path(path)
    source = str(path)
    tlog = path.suffix.lower() == ".tlog"
    if system is not None and not tlog:
        raise InvalidInputError(
            "--mavlink-system",
            f"{source}: a DataFlash log is written on one vehicle and names no MAVLink system: "
            "leave --mavlink-system out",
        )
    chatter = io.StringIO()  # pymavlink prints every damaged header it skips
    log = _open(path, chatter)
    cut = _cut_at(log, path)
    kind = "MAVLink telemetry log" if tlog else "ArduPilot DataFlash"
    vehicle, which = camera_system(_read(log, source, kind, chatter), source, system)
    cut = cut or _packet_cut(log, path)
    seen = vehicle.seen
    rows = {**vehicle.rows, "rng": _heights(vehicle.rows["rng"])}
    rows["trig"], camera = _shutters(vehicle.rows["trig"], vehicle.repeated)
    ignored = _ignored(vehicle.ignored)
    if not rows["pos"] and not rows["gps"]:
        raise InvalidInputError(
            source,
            "no POS / GLOBAL_POSITION_INT / GPS message: the log holds no position"
            + "".join(f" ({x})" for x in (which, ignored) if x),
        )

    def series(key: str, name: str, angles: tuple[int, ...] = ()) -> Series | None:
        got = rows[key]
        if not got:
            return None
        return Series.build(name, [t for t, _ in got], [v for _, v in got], angles, source=source)

    trig = np.sort(np.array([t for t, _ in rows["trig"]], dtype=np.float64))
    notes, damage = _notes(rows, chatter, cut, which, camera)
    home, home_note = _home(vehicle, source)
    notes += [x for x in (ignored, home_note) if x]
    first_t = (rows["att"] or rows["pos"] or rows["gps"])[0][0]
    return LogTrack(
        source=source,
        kind=kind,
        attitude=series("att", "ATT" if "ATT" in seen else "ATTITUDE", (2,)),
        position=series("pos", "POS" if "POS" in seen else "GLOBAL_POSITION_INT"),
        gnss=_receiver(series("gps", "GPS" if "GPS" in seen else "GPS_RAW_INT"), vehicle.hacc),
        height=series("rng", "RFND" if "RFND" in seen else "DISTANCE_SENSOR"),
        triggers_s=trig if trig.size else None,
        home=home,
        utc_offset_s=0.0 if first_t > 1e9 else None,
        notes=tuple(notes),
        damage=damage,
        height_along_body=True,
    )


def _home(vehicle: System, source: str) -> tuple[Series | None, str | None]:
    """The home altitudes ``vehicle`` logged (:func:`home_series`) and their note; none from a
    log without a position from the estimator (a receiver's alone: its heights then need the
    ground given)."""
    if not vehicle.home:
        return None, None
    return home_series(
        "POS.Alt - RelHomeAlt"
        if "POS" in vehicle.seen
        else "GLOBAL_POSITION_INT alt - relative_alt",
        [t for t, _ in vehicle.home],
        [v[0] for _, v in vehicle.home],
        source=source,
    )


def _ignored(ignored: dict[str, str]) -> str | None:
    """What the notes say of the message types ignored, by the column their format lacks."""
    if not ignored:
        return None
    named = ", ".join(f"{name} (no column {column})" for name, column in sorted(ignored.items()))
    return f"messages in a format this importer does not read, ignored: {named}"


def _shutters(messages: list[Row], repeated: dict[str, int]) -> tuple[list[Row], str]:
    """The camera messages of the first of :data:`TRIGGERS` logged (one per photo), and what
    they are: a photo logged as both ``CAM`` and ``TRIG`` counted twice before; how many of
    them told of a photo again (``repeated``, dropped: :func:`_shutter`)."""
    ranks = sorted({int(v[0]) for _, v in messages})
    if not ranks:
        return [], ""
    kept = [m for m in messages if m[1][0] == ranks[0]]
    name = TRIGGERS[ranks[0]]
    again = repeated.get(name, 0)
    said = [name]
    if again:
        said.append(
            f"{again} more {name} of the same photos (each received again, as over a "
            "second link) dropped"
        )
    if len(ranks) > 1:
        said.append(", ".join(TRIGGERS[r] for r in ranks[1:]) + " of the same photos set aside")
    return kept, "; ".join(said)


def _notes(
    rows: dict[str, list[Row]],
    chatter: io.StringIO,
    cut: str | None,
    which: str | None,
    camera: str,
) -> tuple[list[str], str | None]:
    """The track's notes (the MAVLink system read, ``which``; damaged headers skipped; no
    attitude; the camera triggers, ``camera`` saying which messages; where the log ends
    mid-message, ``cut``) and its damage."""
    triggers = len(rows["trig"])
    notes = [f"{triggers} camera trigger(s) from {camera}"] if triggers else []
    if not rows["att"]:
        notes.insert(
            0,
            "no ATT / ATTITUDE message: every frame's attitude assumed level, its yaw from the "
            "GNSS course (frames marked attitude_assumed)",
        )
    damaged = chatter.getvalue().count("bad header")
    skipped = f"{damaged} damaged message headers skipped" if damaged else None
    if skipped:
        notes.insert(0, f"the log is damaged ({skipped}); read past the damage")
    if which:
        notes.insert(0, which)
    if cut:
        notes.append(f"the log {cut}; the samples before it are kept")
    damage = "; ".join(x for x in (skipped, cut and f"it {cut}") if x) or None
    return notes, damage
