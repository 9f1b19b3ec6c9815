"""A folder of photos whose EXIF/XMP metadata is the telemetry (survey drones: DJI and others),
read by :func:`c3_matcher_tools.dataset.sources.images.read_photo_metadata`.

Per photo: position from its EXIF GPS (a photo without one is skipped, with the reason);
attitude from the XMP gimbal angles (the camera's own pointing, turned into the body attitude
that points the calibration's camera mount the same way), else the aircraft's XMP angles, else
marked ``attitude_assumed``; height above ground from the XMP ``RelativeAltitude`` (above the
take-off point: right over flat ground) unless a ground elevation or DEM is given, then EXIF
altitude minus the ground. Time: the EXIF capture time (file order, 1 s apart, when no photo
states one; a photo without one among photos that do is skipped: its place is unknown, and so
is a photo whose time lies more than :data:`PHOTO_TIMES_APART_S` from the others', a camera
clock reset). A byte-for-byte copy of another photo is skipped, naming it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.images import folder_shots, unique_photos
from c3_matcher_tools.dataset.sources.pairing import times_apart, utc_text
from c3_matcher_tools.dataset.sources.track import (
    LogTrack,
    Series,
    Shot,
    body_attitude_for_camera,
    gimbal_camera_matrix,
)

__all__ = ["PHOTO_TIMES_APART_S", "photo_attitude", "read_photo_folder"]

KIND = "photo EXIF/XMP"
PHOTO_TIMES_APART_S = 86400.0
"""A photo whose capture time lies farther than this from every other photo's (:func:`times_apart`,
the largest group kept) is no part of the flight's sequence: one flight's photos are taken within
hours (a battery lasts under one), so a day between them is a camera clock that was reset (to
1970, 2000...) or another day's photo, and sorting it by that time would put it first or last."""


def read_photo_folder(
    folder: Path, *, relative_height: bool = True
) -> tuple[LogTrack, list[Shot], list[tuple[str, str]]]:
    """(track, photos with a position, [(photo, why skipped)]); ``relative_height``: take the
    height above ground from ``RelativeAltitude`` (False when the ground's altitude is given)."""
    folder = Path(folder)
    shots, skipped = unique_photos(folder_shots(folder))
    kept: list[Shot] = []
    timed = any("t_s" in s.own for s in shots if "lat" in s.own)
    for i, s in enumerate(shots):
        if "lat" not in s.own and not s.read():  # refused as any unreadable image is
            raise InvalidInputError("IMAGES", f"{folder / s.name}: an empty file, not an image")
        if "lat" not in s.own:
            skipped.append((s.name, "no GPS position in its EXIF"))
            continue
        if timed and "t_s" not in s.own:  # file order means nothing among timed photos
            skipped.append((s.name, "no EXIF capture time, while the others state theirs"))
            continue
        own = dict(s.own)
        if relative_height and "relative_alt_m" in own:
            own["height_m"] = float(own["relative_alt_m"])
            own["height_source"] = "XMP RelativeAltitude (above the take-off point)"
        t = float(own["t_s"]) if "t_s" in own else float(i)
        kept.append(Shot(s.name, s.read, s.suffix, t, own))
    if not kept:
        raise InvalidInputError(
            str(folder), f"none of the {len(shots)} photo(s) has a GPS position in its EXIF"
        )
    if timed:
        kept = _without_times_apart(kept, skipped)
    kept.sort(key=lambda s: (s.t_s or 0.0, s.name))
    times = [s.t_s or 0.0 for s in kept]
    values = [
        [s.own["lat"], s.own["lon"], s.own.get("alt_m", math.nan), math.nan, 3.0] for s in kept
    ]
    track = LogTrack(
        source=str(folder),
        kind=KIND,
        attitude=None,
        position=None,
        gnss=Series.build("EXIF GPS", np.asarray(times), np.asarray(values), source=str(folder)),
        utc_offset_s=0.0,
        per_image=True,
        notes=() if timed else ("no EXIF capture time: photos taken 1 s apart in file order",),
    )
    return track, kept, skipped


def _without_times_apart(shots: list[Shot], skipped: list[tuple[str, str]]) -> list[Shot]:
    """``shots`` but those whose capture time lies apart from the others' (more than
    :data:`PHOTO_TIMES_APART_S`), each added to ``skipped`` with the reason."""
    times = [float(s.t_s or 0.0) for s in shots]
    apart = set(times_apart(times, PHOTO_TIMES_APART_S))
    if not apart:
        return shots
    rest = [t for i, t in enumerate(times) if i not in apart]
    others = f"{utc_text(min(rest))} .. {utc_text(max(rest))}"
    for i in sorted(apart):
        why = (
            f"its EXIF capture time ({utc_text(times[i])}) lies more than a day apart from the "
            f"other photos' ({others}): a camera clock reset, or another day's photo? Its place "
            "in the flight is unknown"
        )
        skipped.append((shots[i].name, why))
    return [s for i, s in enumerate(shots) if i not in apart]


def photo_attitude(
    calibration: CameraCalibration,
) -> Callable[[Shot, float], tuple[float, float, float] | None]:
    """``attitude_of(shot, t)`` for :func:`write_imported_flight`: the body attitude from the
    photo's gimbal angles (else the aircraft's), None when the photo states neither."""

    def attitude_of(shot: Shot, t: float) -> tuple[float, float, float] | None:
        own = shot.own
        if all(f"Gimbal{a}Degree" in own for a in ("Roll", "Pitch", "Yaw")):
            r = gimbal_camera_matrix(
                own["GimbalRollDegree"], own["GimbalPitchDegree"], own["GimbalYawDegree"]
            )
            return body_attitude_for_camera(r, calibration)
        if all(f"Flight{a}Degree" in own for a in ("Roll", "Pitch", "Yaw")):
            return (own["FlightRollDegree"], own["FlightPitchDegree"], own["FlightYawDegree"])
        return None

    return attitude_of
