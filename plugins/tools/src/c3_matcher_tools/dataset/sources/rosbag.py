"""ROS 1 and ROS 2 bags (ROS 2: sqlite3 or MCAP storage), read with ``rosbags`` and
``rosbags-image`` (the tools' ``logs`` extra).

Topics (each chosen by option; by default the bag's only topic of that type):
images ``sensor_msgs/CompressedImage`` or ``sensor_msgs/Image``; attitude ``sensor_msgs/Imu``
(or ``geometry_msgs/PoseStamped`` / ``nav_msgs/Odometry``) orientation, ENU world and FLU body
as REP 103 says (turned into NED / FRD here; an Imu sample marked as stating no orientation,
``orientation_covariance[0]`` = -1, and a quaternion of about zero norm are skipped); position
``sensor_msgs/NavSatFix`` (altitude above the WGS84 ellipsoid, as the message defines it: the
track says so, :attr:`~.track.LogTrack.ellipsoidal`, and the import brings it to sea level with
``--geoid-height``; horizontal accuracy from its covariance; ``status`` < 0: no fix); intrinsics
``sensor_msgs/CameraInfo`` (plumb_bob / rational_polynomial, or no model and no distortion; any
other model refused; D padded with zeros to a count OpenCV takes) when recorded. Times: each
message's header stamp (UTC seconds), the bag's receive time when the stamp is zero. A raw
``Image`` is stored as PNG (lossless), a ``CompressedImage`` as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher.dto import CameraCalibration
from c3_matcher.dto.camera import FISHEYE_LENS_MODELS, OTHER_LENS_MODEL_FIX
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.images import check_frame_step
from c3_matcher_tools.dataset.sources.track import (
    MIN_QUATERNION_NORM,
    LogTrack,
    Series,
    Shot,
    attitude_from_matrix,
    constant,
    logs_library,
)

__all__ = ["BagTopics", "read_bag"]

KIND = "ROS bag"
IMAGE_TYPES = ("sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image")
ATTITUDE_TYPES = ("sensor_msgs/msg/Imu", "geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry")
NAVSAT_TYPES = ("sensor_msgs/msg/NavSatFix",)
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
_NED_FROM_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class BagTopics:
    """Topic names chosen by the user (None: the bag's only topic of that kind)."""

    image: str | None = None
    attitude: str | None = None
    navsat: str | None = None
    camera_info: str | None = None


def _reader(path: Path) -> Any:
    highlevel = logs_library("rosbags.highlevel", path, "a ROS bag")
    typesys = logs_library("rosbags.typesys", path, "a ROS bag")
    if not path.exists():
        raise InvalidInputError(str(path), "no such bag")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise InvalidInputError(
            str(path),
            "a folder without metadata.yaml, which a ROS 2 bag's folder holds (beside its .db3 or "
            ".mcap files): give the bag's folder, or a ROS 1 .bag or an MCAP file",
        )
    bag = path.parent if path.is_file() and path.suffix in (".db3", ".mcap") else path
    if path.is_file() and not (bag / "metadata.yaml").is_file() and path.suffix != ".bag":
        bag = path  # a bare MCAP file: rosbags reads it through its directory-less path
    try:
        reader = highlevel.AnyReader(
            [bag], default_typestore=typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
        )
        reader.open()
    except Exception as exc:
        raise InvalidInputError(str(path), f"not a readable ROS bag: {exc}") from None
    return reader


def _pick(reader: Any, source: str, wanted: str | None, types: Sequence[str], what: str) -> Any:
    conns = reader.connections
    if wanted is not None:
        hit = [c for c in conns if c.topic == wanted]
        if not hit:
            names = ", ".join(sorted({c.topic for c in conns}))
            raise InvalidInputError(source, f"no topic {wanted} in the bag (topics: {names})")
        if hit[0].msgtype not in types:
            raise InvalidInputError(
                source, f"{wanted} is {hit[0].msgtype}, not {' or '.join(types)} ({what})"
            )
        return hit
    hit = [c for c in conns if c.msgtype in types]
    topics = sorted({c.topic for c in hit})
    if len(topics) > 1:
        raise InvalidInputError(
            source, f"several {what} topics ({', '.join(topics)}): choose one by option"
        )
    return hit or None


def _stamp(msg: Any, received_ns: int) -> float:
    st = msg.header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(st.nanosec)
    return (ns or received_ns) / 1e9


def _orientation(msg: Any) -> Any:
    if hasattr(msg, "orientation"):
        return msg.orientation
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return pose.orientation


def _stated_orientation(msg: Any) -> Any | None:
    """The orientation an attitude message states; None when it states none: an Imu marked so
    (``orientation_covariance[0]`` = -1, as sensor_msgs/Imu says) or a quaternion of about zero
    norm."""
    if hasattr(msg, "orientation_covariance") and float(msg.orientation_covariance[0]) == -1.0:
        return None
    q = _orientation(msg)
    norm = math.sqrt(sum(float(c) ** 2 for c in (q.w, q.x, q.y, q.z)))
    return q if norm >= MIN_QUATERNION_NORM else None


def _attitude_ned(q: Any) -> tuple[float, float, float]:
    from c3_matcher_tools.dataset.sources.track import quaternion_matrix

    r_enu_flu = quaternion_matrix(float(q.w), float(q.x), float(q.y), float(q.z))
    return attitude_from_matrix(_NED_FROM_ENU @ r_enu_flu @ _FLU_FROM_FRD)


DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
"""The CameraInfo distortion models whose coefficients are OpenCV's (k1, k2, p1, p2, k3[, ...])."""


def _info_field(msg: Any, name: str) -> Any:
    """A CameraInfo field by its ROS 2 name (``d``, ``k``) or its ROS 1 one (``D``, ``K``)."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def _calibration(msg: Any, source: str) -> CameraCalibration:
    """A CameraInfo's intrinsics (ROS 1 or ROS 2 spelling); refused naming its distortion model
    when that is neither of :data:`DISTORTION_MODELS` (nor absent with no distortion): e.g. a
    fisheye ``equidistant`` model, whose coefficients OpenCV's pinhole model would misread."""
    d = np.asarray(_info_field(msg, "d"), dtype=np.float64).reshape(-1)
    model = str(getattr(msg, "distortion_model", "") or "")
    if model not in DISTORTION_MODELS and (model or np.any(d != 0)):
        raise InvalidInputError(source, _unsupported_model(model))
    d = _opencv_sized(d, source)
    try:
        k = np.asarray(_info_field(msg, "k"), dtype=np.float64).reshape(3, 3)
        return CameraCalibration(k, d, (int(msg.width), int(msg.height)))
    except (InvalidInputError, ValueError) as exc:  # K of zeros: a camera never calibrated
        raise InvalidInputError(
            source,
            f"its CameraInfo states no usable intrinsics ({exc}): give the camera's "
            "calibration JSON",
        ) from None


def _unsupported_model(model: str) -> str:
    """Why a CameraInfo of distortion model ``model`` (not one of :data:`DISTORTION_MODELS`) is
    refused, and what to do: a fisheye model is no pinhole one, whatever file gives it; an
    unnamed one is for the user to say (its coefficients may be OpenCV's or not)."""
    known = " or ".join(DISTORTION_MODELS)
    said = f"CameraInfo distortion model {model!r} is not supported (only {known})"
    if not model:
        return (
            f"{said}: its coefficients are of no named model; give the camera's calibration "
            "JSON, its distortion OpenCV's k1, k2, p1, p2[, k3...]"
        )
    if model.lower() in FISHEYE_LENS_MODELS:
        return f"{said}: a fisheye lens model; {OTHER_LENS_MODEL_FIX}"
    return f"{said}: {OTHER_LENS_MODEL_FIX}"


OPENCV_DISTORTION_SIZES = (0, 4, 5, 8, 12, 14)
"""How many distortion coefficients OpenCV takes: a CameraInfo's D of another count is padded
with zeros to the next (the terms it leaves out are zero)."""


def _opencv_sized(d: NDArray[np.float64], source: str) -> NDArray[np.float64]:
    """``d`` padded with zeros to the next count OpenCV takes (6 or 7 -> 8, 9 to 11 -> 12,
    13 -> 14): no coefficient dropped; refused naming its count beyond 14."""
    if d.size > OPENCV_DISTORTION_SIZES[-1]:
        raise InvalidInputError(
            source,
            f"its CameraInfo gives {d.size} distortion coefficients: OpenCV's model takes at "
            f"most {OPENCV_DISTORTION_SIZES[-1]}",
        )
    size = next(n for n in OPENCV_DISTORTION_SIZES if n >= d.size)
    return np.pad(d, (0, size - d.size))


def _image_bytes(msg: Any, msgtype: str) -> tuple[bytes, str]:
    import cv2

    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format).lower()
        return bytes(msg.data), ".png" if "png" in fmt else ".jpg"
    from rosbags.image import message_to_cvimage

    bgr = message_to_cvimage(msg, "bgr8")
    ok, png = cv2.imencode(".png", bgr)
    if not ok:
        raise InvalidInputError("IMAGES", "a raw image of the bag cannot be encoded")
    return png.tobytes(), ".png"


ASSUMED_LEVEL = (
    "every frame's attitude assumed level, its yaw from the GNSS course (frames marked "
    "attitude_assumed)"
)
NO_ATTITUDE = (
    "no sensor_msgs/Imu, PoseStamped or Odometry topic (--attitude-topic names one): "
    + ASSUMED_LEVEL
)


@dataclass(frozen=True)
class _Connections:
    """The bag's connections read, by kind: ``attitude`` empty when the bag has none,
    ``camera_info`` None when no intrinsics were recorded."""

    images: list[Any]
    attitude: list[Any]
    navsat: list[Any]
    camera_info: list[Any] | None

    @property
    def wanted(self) -> list[Any]:
        return [*self.images, *self.attitude, *self.navsat, *(self.camera_info or [])]


@dataclass(frozen=True)
class _Messages:
    """What the chosen topics held, in the bag's order: the kept images, the attitude and
    NavSatFix samples (times and values), the first CameraInfo and how many attitude samples
    stated no orientation (skipped)."""

    shots: list[Shot]
    att_t: list[float]
    att_v: list[tuple[float, float, float]]
    fix_t: list[float]
    fix_v: list[list[float]]
    info: Any | None
    no_orientation: int = 0


def read_bag(
    path: Path, topics: BagTopics = BagTopics(), step: int = 1, *, intrinsics: bool = True
) -> tuple[LogTrack, list[Shot], CameraCalibration | None]:
    """The track, every ``step``-th image and the recorded intrinsics (None when no
    CameraInfo, or not ``intrinsics``: not wanted, their distortion model then unchecked) of a
    bag (see the module docstring); raises InvalidInputError naming a missing image or position
    topic. A bag without attitude (or whose attitude topic states none) is read, and said so in
    its notes: each frame is then imported level with the yaw of its GNSS course and marked
    ``attitude_assumed``, as from any log without attitude."""
    check_frame_step(step, video=True)
    path = Path(path)
    source = str(path)
    conns, messages, calibration = _read(_reader(path), source, topics, step, intrinsics)
    _check_messages(source, conns, messages)
    attitude = (
        _series(conns.attitude[0].topic, messages.att_t, messages.att_v, source, angles=(2,))
        if messages.att_t
        else None
    )
    gnss = _series(conns.navsat[0].topic, messages.fix_t, messages.fix_v, source)
    shots = sorted(messages.shots, key=lambda s: s.t_s or 0.0)
    track = LogTrack(
        source=source,
        kind=KIND,
        attitude=attitude,
        position=None,
        gnss=gnss,
        utc_offset_s=0.0,
        notes=_notes(conns, messages, bool(messages.att_t)),
        ellipsoidal=True,
    )
    return track, shots, calibration


def _read(
    reader: Any, source: str, topics: BagTopics, step: int, intrinsics: bool
) -> tuple[_Connections, _Messages, CameraCalibration | None]:
    """The chosen connections, their messages and the first CameraInfo's intrinsics (when
    wanted, ``intrinsics``, and recorded); the reader is closed after. Any failure of the bag's
    reader or of a message read is refused as an unreadable bag."""
    try:
        conns = _connections(reader, source, topics)
        messages = _messages(reader, conns, step)
        info = messages.info
        calibration = _calibration(info, source) if intrinsics and info is not None else None
        return conns, messages, calibration
    except InvalidInputError:
        raise
    except Exception as exc:
        raise InvalidInputError(source, f"unreadable ROS bag: {exc}") from None
    finally:
        reader.close()


def _connections(reader: Any, source: str, topics: BagTopics) -> _Connections:
    """The topics to read, each chosen by ``topics`` or the only one of its type; refused
    when the bag has no image or no NavSatFix topic."""
    images = _pick(reader, source, topics.image, IMAGE_TYPES, "image")
    if images is None:
        raise InvalidInputError(
            source, "no sensor_msgs/Image or CompressedImage topic: the bag holds no images"
        )
    attitude = _pick(reader, source, topics.attitude, ATTITUDE_TYPES, "attitude") or []
    navsat = _pick(reader, source, topics.navsat, NAVSAT_TYPES, "NavSatFix")
    if navsat is None:
        raise InvalidInputError(
            source, "no sensor_msgs/NavSatFix topic: the bag holds no position (--navsat-topic)"
        )
    info = _pick(reader, source, topics.camera_info, INFO_TYPES, "CameraInfo")
    return _Connections(images, attitude, navsat, info)


def _messages(reader: Any, conns: _Connections, step: int) -> _Messages:
    """Every message of the chosen topics: every ``step``-th image kept, each attitude sample
    that states an orientation and each NavSatFix sample at its stamp, the first CameraInfo."""
    shots: list[Shot] = []
    att_t: list[float] = []
    att_v: list[tuple[float, float, float]] = []
    fix_t: list[float] = []
    fix_v: list[list[float]] = []
    info = None
    seen_images = no_orientation = 0
    for conn, received, raw in reader.messages(connections=conns.wanted):
        msg = reader.deserialize(raw, conn.msgtype)
        t = _stamp(msg, received)
        if conn.msgtype in IMAGE_TYPES:
            seen_images += 1
            if (seen_images - 1) % step:
                continue
            data, suffix = _image_bytes(msg, conn.msgtype)
            name = f"{conn.topic}@{t:.6f}#{seen_images - 1}"  # unique where stamps are alike
            shots.append(Shot(name, constant(data), suffix, t, {"stamp_s": t}))
        elif conn.msgtype in ATTITUDE_TYPES:
            q = _stated_orientation(msg)
            no_orientation += q is None
            if q is not None:
                att_t.append(t)
                att_v.append(_attitude_ned(q))
        elif conn.msgtype in NAVSAT_TYPES:
            fix_t.append(t)
            fix_v.append(_fix(msg))
        elif info is None:
            info = msg
    return _Messages(shots, att_t, att_v, fix_t, fix_v, info, no_orientation)


def _fix(msg: Any) -> list[float]:
    """A NavSatFix as lat, lon, alt, horizontal accuracy (m, NaN without a covariance) and fix
    type (3; 0 with no position when the receiver has no fix)."""
    cov = np.asarray(msg.position_covariance, dtype=np.float64)
    acc = math.sqrt(max(cov[0], cov[4])) if int(msg.position_covariance_type) > 0 else math.nan
    has_fix = int(msg.status.status) >= 0
    return [
        msg.latitude if has_fix else math.nan,
        msg.longitude if has_fix else math.nan,
        msg.altitude if has_fix else math.nan,
        acc,
        3.0 if has_fix else 0.0,
    ]


def _check_messages(source: str, conns: _Connections, messages: _Messages) -> None:
    """Refuse a chosen image, attitude or NavSatFix topic without a message."""
    if not messages.shots:
        raise InvalidInputError(source, f"no message on the image topic {conns.images[0].topic}")
    if conns.attitude and not messages.att_t and not messages.no_orientation:
        raise InvalidInputError(
            source, f"no message on the attitude topic {conns.attitude[0].topic}"
        )
    if not messages.fix_t:
        raise InvalidInputError(
            source, f"no message on the NavSatFix topic {conns.navsat[0].topic}"
        )


def _series(
    name: str,
    t: list[float],
    values: Sequence[Sequence[float]],
    source: str,
    angles: tuple[int, ...] = (),
) -> Series:
    """The samples of one topic in time order (a stable sort: equal stamps keep the bag's
    order)."""
    order = np.argsort(t, kind="stable")
    return Series.build(
        name, np.asarray(t)[order], np.asarray(values)[order], angles, source=source
    )


def _notes(conns: _Connections, messages: _Messages, attitude: bool) -> tuple[str, ...]:
    """The topics read, images stamped alike (:func:`_alike`), and :data:`NO_ATTITUDE` when
    the bag has no attitude topic; the attitude samples skipped for stating no orientation, and
    the attitude then assumed when none did."""
    topics = (
        f"images {conns.images[0].topic}, attitude "
        + (conns.attitude[0].topic if conns.attitude else "none")
        + f", position {conns.navsat[0].topic}, intrinsics "
        + (conns.camera_info[0].topic if conns.camera_info else "not recorded")
    )
    notes = [topics, *_alike(messages.shots)]
    no_orientation = messages.no_orientation
    if not conns.attitude:
        return (*notes, NO_ATTITUDE)
    if not no_orientation:
        return tuple(notes)
    skipped = (
        f"{no_orientation} {conns.attitude[0].topic} sample(s) state no orientation "
        "(orientation_covariance[0] = -1, or a zero quaternion): skipped"
    )
    return (*notes, skipped if attitude else f"{skipped}; {ASSUMED_LEVEL}")


def _alike(shots: Sequence[Shot]) -> list[str]:
    """A note when images share a header stamp (a message recorded twice, or a driver stamping
    frames alike): each is named by its index in the topic (``#k``) and imported at that time;
    a copy of another's bytes is set aside by the import."""
    stamps: dict[float | None, int] = {}
    for shot in shots:
        stamps[shot.t_s] = stamps.get(shot.t_s, 0) + 1
    shared = [n for n in stamps.values() if n > 1]
    if not shared:
        return []
    return [
        f"{sum(shared)} images at {len(shared)} header stamp(s) that several share (a message "
        "recorded twice, or frames stamped alike): each named by its index in the topic (#k), "
        "placed at its stamp"
    ]
