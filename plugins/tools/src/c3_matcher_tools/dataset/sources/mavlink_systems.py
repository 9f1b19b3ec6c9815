"""Which MAVLink system of a telemetry log is the camera vehicle. A ground station records every
system on its link, each read apart (:class:`System`): a second aircraft, or an antenna tracker
sending its own position, would otherwise be taken for the vehicle. One flight is imported at a
time: the system that sent camera feedback, or the one given (``--mavlink-system``); a log where
that cannot be told is refused, naming the systems and what each sent."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from c3_matcher.errors import InvalidInputError

__all__ = ["MOVING_M", "System", "camera_system"]

Row = tuple[float, list[float]]


@dataclass(frozen=True)
class System:
    """What one MAVLink system's messages said (a DataFlash log's: all of them): the samples by
    kind, the home altitude at each position sample (its altitude minus its altitude above
    home), the ``GPA.HAcc`` accuracies, the message types seen and those ignored (by the column
    their format lacks); the photos its camera messages told of (:func:`photo`) and, per camera
    message type, how many told of a photo again (dropped)."""

    rows: dict[str, list[Row]] = field(
        default_factory=lambda: {k: [] for k in ("att", "pos", "gps", "rng", "trig")}
    )
    home: list[Row] = field(default_factory=list)
    hacc: list[tuple[float, float]] = field(default_factory=list)
    seen: set[str] = field(default_factory=set)
    ignored: dict[str, str] = field(default_factory=dict)
    photos: set[tuple[Any, ...]] = field(default_factory=set)
    repeated: dict[str, int] = field(default_factory=dict)


MOVING_M = 20.0
"""A system whose positions span more than this is said to move: a receiver standing still (a
ground station, an antenna tracker) wanders a few metres with GNSS noise, a vehicle taking photos
of the ground covers far more. It only describes the systems in a refusal; it chooses none."""


def camera_system(
    systems: dict[int, System], source: str, chosen: int | None = None
) -> tuple[System, str | None]:
    """The camera vehicle's messages, and a note saying whose they are when the log holds
    several MAVLink systems (a ground station's link to several vehicles): system ``chosen``
    when given, else the one that sent camera feedback (CAMERA_FEEDBACK / CAMERA_TRIGGER), else
    the only one that sent a position. Refused, naming the systems and what each sent, when
    several sent camera feedback, or none did and several sent positions."""
    numbers = sorted(systems)
    named = ", ".join(map(str, numbers))
    listed = f"MAVLink system{'s' if len(numbers) > 1 else ''} {named} in the log"
    if chosen is not None:
        if chosen not in systems:
            raise InvalidInputError(
                "--mavlink-system",
                f"{source}: no MAVLink system {chosen} in the log; it holds "
                + _described(systems, numbers),
            )
        return systems[chosen], f"{listed}: read system {chosen} (given by --mavlink-system)"
    if len(systems) == 1:
        return systems[numbers[0]], None
    cameras = [n for n in numbers if systems[n].rows["trig"]]
    placed = [n for n in numbers if _positions(systems[n])]
    if len(cameras) > 1:
        raise InvalidInputError(
            source,
            f"camera feedback from MAVLink systems {', '.join(map(str, cameras))}: the log holds "
            "several camera vehicles, and one flight is imported at a time: "
            f"{_described(systems, cameras)}; give --mavlink-system N to read system N",
        )
    if not cameras and len(placed) > 1:
        raise InvalidInputError(source, _which_one(systems, placed))
    if cameras:
        number, why = cameras[0], "its camera feedback"
    else:
        number = (placed or numbers)[0]
        why = "the only one with a position" if placed else "none sent a position"
    return systems[number], f"{listed}: read system {number} ({why})"


def _which_one(systems: dict[int, System], placed: list[int]) -> str:
    """Why a log whose systems ``placed`` all sent positions, and none camera feedback, cannot
    be read for one of them unasked."""
    return (
        f"MAVLink systems {', '.join(map(str, placed))} in the log sent positions and none "
        "sent camera feedback, so which one carried the camera cannot be told (another "
        "aircraft, or an antenna tracker or ground station sending its own position): "
        f"{_described(systems, placed)}; give --mavlink-system N to read system N"
    )


def _described(systems: dict[int, System], numbers: list[int]) -> str:
    """What each of the systems ``numbers`` sent, and whether it moved."""
    return ", ".join(f"system {n} ({_looks(systems[n])})" for n in numbers)


def _looks(system: System) -> str:
    """What ``system`` sent (its samples by kind) and how far its positions spread."""
    kinds = (
        ("pos", "position(s)"),
        ("gps", "GNSS fix(es)"),
        ("att", "attitude(s)"),
        ("trig", "camera message(s)"),
    )
    sent = ", ".join(f"{len(system.rows[key])} {what}" for key, what in kinds)
    points = _positions(system)
    if not points:
        return f"{sent}, no position"
    span = _span_m(points)
    return f"{sent}, {'moves over' if span > MOVING_M else 'stays within'} {span:.0f} m"


def _positions(system: System) -> list[tuple[float, float]]:
    """``system``'s horizontal positions (lat, lon deg): its estimator's, else its receiver's
    fixes (those with a 2D or 3D fix)."""
    estimated = [(v[0], v[1]) for _, v in system.rows["pos"]]
    fixed = [(v[0], v[1]) for _, v in system.rows["gps"] if v[4] >= 2]
    return [p for p in estimated or fixed if math.isfinite(p[0]) and math.isfinite(p[1])]


def _span_m(points: list[tuple[float, float]]) -> float:
    """The diagonal of the box around ``points``, m (locally flat: the spans compared here are
    far below the Earth's curvature)."""
    lats, lons = [p[0] for p in points], [p[1] for p in points]
    metres = 111_320.0  # per degree of latitude, and of longitude at the equator
    north = (max(lats) - min(lats)) * metres
    east = (max(lons) - min(lons)) * metres * math.cos(math.radians(sum(lats) / len(lats)))
    return math.hypot(north, east)


def photo(m: Any) -> tuple[Any, ...] | None:
    """The photo a MAVLink camera message tells of: its type, camera, image number and the
    vehicle's time of it. ArduPilot sends each photo's message on every link, so a ground
    station on two links records it twice, alike; one that differs in any of these is another
    photo. None for a DataFlash camera message (written once, on the vehicle)."""
    name = m.get_type()
    if name == "CAMERA_FEEDBACK":
        return (name, m.cam_idx, m.img_idx, m.time_usec)
    if name == "CAMERA_TRIGGER":
        return (name, m.seq, m.time_usec)
    return None
