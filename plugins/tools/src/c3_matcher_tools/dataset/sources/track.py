"""What a recorded log says, as the importers hand it on: time series (:class:`Series`), the
vehicle's track (:class:`LogTrack`), the images (:class:`Shot`) and the rotations between
quaternions, matrices and Z-Y-X angles.

Conventions: times in seconds on the log's own clock (``t_s``); ``utc_offset_s`` turns it into
UTC (``utc = t_s + utc_offset_s``) when the log says; attitude in degrees, aerospace Z-Y-X
(yaw, pitch, roll) of the BODY in NED, yaw from true north clockwise; latitude/longitude WGS84
degrees; ``alt_m`` above mean sea level, or above the WGS84 ellipsoid where the track says so
(:attr:`LogTrack.ellipsoidal`); heights in metres above the ground.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.camera import body_from_camera
from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError

__all__ = [
    "MIN_QUATERNION_NORM",
    "LogTrack",
    "Series",
    "Shot",
    "attitude_from_matrix",
    "body_attitude_for_camera",
    "constant",
    "cut_short",
    "gimbal_camera_matrix",
    "home_series",
    "logs_library",
    "quaternion_matrix",
]


def logs_library(module: str, path: Path, reading: str) -> Any:
    """``module``, a library of the logs extra, imported to read ``path`` (``reading``: what it
    is); refused naming the extra when it is not installed."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InvalidInputError(
            str(path),
            f"reading {reading} needs the logs extra: pip install 'c3-matcher-tools[logs]'",
        ) from None


def cut_short(at: int, size: int, what: str = "a message") -> str:
    """What a log of ``size`` bytes whose last message (``what``), from byte ``at``, runs past
    its end is said to do: "ends mid-message, cut short ..." (its reader keeps what came
    before)."""
    return f"ends mid-message, cut short at byte {size} in {what} from byte {at}"


@dataclass(frozen=True)
class Series:
    """Samples of one log quantity: ``t_s`` (n,) ascending seconds on the log's clock,
    ``values`` (n, k), NaN where a sample lacks a value; columns listed in ``angles`` are
    degrees and interpolated the short way round. ``name``: the topic / message it came from."""

    name: str
    t_s: F64
    values: F64
    angles: tuple[int, ...] = ()

    @classmethod
    def build(
        cls,
        name: str,
        t_s: Sequence[float] | F64,
        values: Sequence[Sequence[float]] | F64,
        angles: tuple[int, ...] = (),
        *,
        source: str,
    ) -> Series:
        """Check the samples (finite times that never step back) and keep the finite rows;
        raises InvalidInputError naming ``source`` and the topic at a time that is not finite
        (it would hide a jump back) or a backward time jump."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            i = int(bad[0])
            raise InvalidInputError(source, f"sample {i} of {name} has no finite time ({t[i]})")
        steps = np.diff(t)
        back = np.flatnonzero(steps < 0)
        if back.size:
            i = int(back[0])
            raise InvalidInputError(
                source,
                f"time jumps back {-steps[i]:.3f} s at {t[i]:.3f} s in {name} (a log cut and "
                "joined, or two logs in one?)",
            )
        keep = np.any(np.isfinite(v), axis=1)
        v = v[keep].copy()
        for col in angles:
            ok = np.isfinite(v[:, col])
            v[ok, col] = np.degrees(np.unwrap(np.radians(v[ok, col])))
        return cls(name, t[keep], v, angles)

    def __len__(self) -> int:
        return int(self.t_s.size)

    @property
    def span(self) -> tuple[float, float]:
        return (float(self.t_s[0]), float(self.t_s[-1])) if len(self) else (math.nan, math.nan)

    def at(self, t: float, max_gap_s: float) -> F64 | None:
        """The sample at ``t`` when one falls on it exactly; else linear interpolation between
        the samples around it when both are within ``max_gap_s``, else the nearer one when it is
        within ``max_gap_s``; None otherwise."""
        if not len(self):
            return None
        j = int(np.searchsorted(self.t_s, t))
        lo, hi = max(j - 1, 0), min(j, len(self) - 1)
        dlo, dhi = abs(t - self.t_s[lo]), abs(self.t_s[hi] - t)
        if dhi == 0:  # on a sample: itself, not a weighted sum that a NaN beside it would spoil
            out = self.values[hi].copy()
        elif lo != hi and dlo <= max_gap_s and dhi <= max_gap_s and self.t_s[hi] > self.t_s[lo]:
            w = (t - self.t_s[lo]) / (self.t_s[hi] - self.t_s[lo])
            out = (1 - w) * self.values[lo] + w * self.values[hi]
        elif min(dlo, dhi) <= max_gap_s:
            out = self.values[lo if dlo <= dhi else hi].copy()
        else:
            return None
        for col in self.angles:
            out[col] = (out[col] + 180.0) % 360.0 - 180.0
        return np.asarray(out, dtype=np.float64)

    def held(self, t: float) -> F64 | None:
        """The value in force at ``t`` of a quantity that is set now and then and holds until
        set again (a home altitude): the latest sample at or before ``t``, else the first;
        None when there is none."""
        if not len(self):
            return None
        j = int(np.searchsorted(self.t_s, t, side="right")) - 1
        return np.asarray(self.values[max(j, 0)], dtype=np.float64).copy()


HOME_STEP_M = 0.05
"""A home altitude that differs from the one in force by more than this was set again (a log's
altitudes, rounded to the millimetre or to float32, jitter by less)."""


def _when(t_s: float) -> str:
    """A log time as a person reads it: UTC when the log's clock is (past 2001), else s."""
    if t_s < 1e9:
        return f"{t_s:.1f} s"
    return datetime.fromtimestamp(t_s, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def home_series(
    name: str, t_s: Sequence[float] | F64, alt_m: Sequence[float] | F64, *, source: str
) -> tuple[Series | None, str | None]:
    """The home altitudes logged (``name``: where from) as a series read with
    :meth:`Series.held`, None when none is finite; and a note when the home was set again at
    another altitude (PX4 and ArduPilot set it again at arming, the first often before the
    GNSS altitude settled): each altitude and when it was set, on the log's clock."""
    home = Series.build(name, t_s, np.asarray(alt_m, dtype=np.float64), source=source)
    if not len(home):
        return None, None
    v = home.values[:, 0]
    sets = [0]
    for i in range(1, v.size):
        if abs(v[i] - v[sets[-1]]) > HOME_STEP_M:
            sets.append(i)
    if len(sets) == 1:
        return home, None
    shown = ", ".join(f"{v[i]:.1f} m from {_when(home.t_s[i])}" for i in sets[:4])
    more = f" and {len(sets) - 4} more" if len(sets) > 4 else ""
    return home, (
        f"home altitude ({name}) set {len(sets)} times: {shown}{more}; each frame's height is "
        "its altitude minus the home altitude in force at its time"
    )


@dataclass(frozen=True)
class LogTrack:
    """What a log says about the vehicle. ``attitude``: roll, pitch, yaw (deg, body);
    ``position``: lat, lon, alt_m; ``gnss``: the receiver's own lat, lon, alt_m, horizontal
    accuracy (m, NaN when not stated) and fix type (3 = 3D); ``height``: height above ground
    (m, valid samples only, e.g. a rangefinder); ``triggers_s``: camera trigger times;
    ``home``: the ground's altitude at home (same datum as ``alt_m``) as the log set it over
    time, read at a frame's time with :meth:`Series.held` (:func:`home_series`)."""

    source: str
    kind: str
    attitude: Series | None
    position: Series | None
    gnss: Series | None = None
    height: Series | None = None
    triggers_s: F64 | None = None
    home: Series | None = None
    utc_offset_s: float | None = None
    notes: tuple[str, ...] = ()
    per_image: bool = False
    """Each image states its own position (photo metadata): it is used as the GNSS fix."""
    damage: str | None = None
    """What the log's reader said of a damaged or truncated log (read up to the damage)."""
    ellipsoidal: bool = False
    """Its ``alt_m`` (and ``home``) are above the WGS84 ellipsoid, not sea level (a ROS bag's
    NavSatFix, as the message defines it): the import's geoid height brings them to sea level
    before a ground is taken from them."""
    height_along_body: bool = False
    """Its ``height`` is a body-fixed rangefinder's range along the body's down axis (ArduPilot's
    ``RFND``, MAVLink ``DISTANCE_SENSOR``), longer than the height when the vehicle tilts: made
    vertical with the attitude at each frame's time (PX4's ``dist_bottom`` is vertical already)."""

    @property
    def span(self) -> tuple[float, float]:
        """First and last time of the position (or GNSS) samples."""
        pos = self.position if self.position is not None and len(self.position) else self.gnss
        return pos.span if pos is not None else (math.nan, math.nan)


@dataclass(frozen=True)
class Shot:
    """One image: ``name`` (as the user knows it), ``read`` returns its encoded bytes,
    ``suffix`` its file suffix, ``t_s`` its own clock (UTC seconds for EXIF / bag stamps) when
    known; ``own`` carries what the image itself records (EXIF position, gimbal angles...)."""

    name: str
    read: Callable[[], bytes]
    suffix: str = ".jpg"
    t_s: float | None = None
    own: dict[str, Any] = field(default_factory=dict)


def constant(data: bytes) -> Callable[[], bytes]:
    """A :attr:`Shot.read` for bytes already in memory."""
    return lambda: data


def attitude_from_matrix(r_world_from_body: F64) -> tuple[float, float, float]:
    """(roll, pitch, yaw) degrees, Z-Y-X, of a NED-from-FRD rotation matrix."""
    r = np.asarray(r_world_from_body, dtype=np.float64)
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    roll = math.atan2(float(r[2, 1]), float(r[2, 2]))
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


MIN_QUATERNION_NORM = 1e-3
"""A recorded quaternion shorter than this states no orientation (ROS 1's all-zero default,
PX4's before its estimator runs): its sample is skipped, never normalised."""


def quaternion_matrix(w: float, x: float, y: float, z: float) -> F64:
    """Rotation matrix of the unit quaternion (w, x, y, z) (Hamilton, active)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def body_attitude_for_camera(
    r_world_from_camera: F64, calibration: CameraCalibration
) -> tuple[float, float, float]:
    """The body attitude (deg) that, with the calibration's camera mount, points the camera as
    ``r_world_from_camera`` (NED from camera x right, y down, z along the optical axis) does:
    how a gimbal camera's own angles become the dataset's attitude."""
    mount = body_from_camera(calibration)
    return attitude_from_matrix(np.asarray(r_world_from_camera) @ mount.T)


def gimbal_camera_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """NED-from-camera rotation of a gimbal camera given as Z-Y-X angles of its forward axis
    (pitch -90 looks straight down, yaw is the camera's heading; image top toward the heading
    when it looks down), as DJI and others record them."""
    from c3_matcher.camera import rot_x, rot_y, rot_z

    forward_from_camera = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    yaw, pitch, roll = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    r = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
    return np.asarray(r @ forward_from_camera, dtype=np.float64)
