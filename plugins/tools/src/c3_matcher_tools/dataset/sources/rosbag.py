"""ROS 1 and ROS 2 bags (ROS 2: sqlite3 or MCAP storage), read with ``rosbags`` and
``rosbags-image`` (the tools' ``logs`` extra).

Topics (each chosen by option; by default the bag's only topic of that type):
images ``sensor_msgs/CompressedImage`` or ``sensor_msgs/Image``; attitude ``sensor_msgs/Imu``
(or ``geometry_msgs/PoseStamped`` / ``nav_msgs/Odometry``) orientation, ENU world and FLU body
as REP 103 says (turned into NED / FRD here); position ``sensor_msgs/NavSatFix`` (altitude above
the ellipsoid or sea level as the receiver gives it; horizontal accuracy from its covariance;
``status`` < 0: no fix); intrinsics ``sensor_msgs/CameraInfo`` (plumb_bob / rational_polynomial)
when recorded. Times: each message's header stamp (UTC seconds), the bag's receive time when
the stamp is zero. A raw ``Image`` is stored as PNG (lossless), a ``CompressedImage`` as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.images import check_frame_step
from c3_matcher_tools.dataset.sources.track import (
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


def _attitude_ned(q: Any) -> tuple[float, float, float]:
    from c3_matcher_tools.dataset.sources.track import quaternion_matrix

    r_enu_flu = quaternion_matrix(float(q.w), float(q.x), float(q.y), float(q.z))
    return attitude_from_matrix(_NED_FROM_ENU @ r_enu_flu @ _FLU_FROM_FRD)


def _calibration(msg: Any) -> CameraCalibration:
    d = np.asarray(msg.d, dtype=np.float64)
    if d.size not in (0, 4, 5, 8, 12, 14):
        d = d[:5] if d.size > 5 else np.pad(d, (0, 5 - d.size))
    return CameraCalibration(
        np.asarray(msg.k, dtype=np.float64).reshape(3, 3), d, (int(msg.width), int(msg.height))
    )


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


NO_ATTITUDE = (
    "no sensor_msgs/Imu, PoseStamped or Odometry topic (--attitude-topic names one): every "
    "frame's attitude assumed level, its yaw from the GNSS course (frames marked "
    "attitude_assumed)"
)


def read_bag(
    path: Path, topics: BagTopics = BagTopics(), step: int = 1
) -> tuple[LogTrack, list[Shot], CameraCalibration | None]:
    """The track, every ``step``-th image and the recorded intrinsics (None when no
    CameraInfo) of a bag (see the module docstring); raises InvalidInputError naming a missing
    image or position topic. A bag without attitude is read, and said so in its notes: each
    frame is then imported level with the yaw of its GNSS course and marked
    ``attitude_assumed``, as from any log without attitude."""
    check_frame_step(step, video=True)
    path = Path(path)
    source = str(path)
    reader = _reader(path)
    try:
        images = _pick(reader, source, topics.image, IMAGE_TYPES, "image")
        if images is None:
            raise InvalidInputError(
                source, "no sensor_msgs/Image or CompressedImage topic: the bag holds no images"
            )
        attitude_c = _pick(reader, source, topics.attitude, ATTITUDE_TYPES, "attitude") or []
        navsat_c = _pick(reader, source, topics.navsat, NAVSAT_TYPES, "NavSatFix")
        if navsat_c is None:
            raise InvalidInputError(
                source, "no sensor_msgs/NavSatFix topic: the bag holds no position (--navsat-topic)"
            )
        info_c = _pick(reader, source, topics.camera_info, INFO_TYPES, "CameraInfo")
        shots: list[Shot] = []
        att_t: list[float] = []
        att_v: list[tuple[float, float, float]] = []
        fix_t: list[float] = []
        fix_v: list[list[float]] = []
        calibration = None
        seen_images = 0
        wanted = [*images, *attitude_c, *navsat_c, *(info_c or [])]
        for conn, received, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            t = _stamp(msg, received)
            if conn.msgtype in IMAGE_TYPES:
                seen_images += 1
                if (seen_images - 1) % step:
                    continue
                data, suffix = _image_bytes(msg, conn.msgtype)
                shots.append(
                    Shot(f"{conn.topic}@{t:.6f}", constant(data), suffix, t, {"stamp_s": t})
                )
            elif conn.msgtype in ATTITUDE_TYPES:
                att_t.append(t)
                att_v.append(_attitude_ned(_orientation(msg)))
            elif conn.msgtype in NAVSAT_TYPES:
                cov = np.asarray(msg.position_covariance, dtype=np.float64)
                acc = (
                    math.sqrt(max(cov[0], cov[4]))
                    if int(msg.position_covariance_type) > 0
                    else math.nan
                )
                has_fix = int(msg.status.status) >= 0
                fix_t.append(t)
                fix_v.append(
                    [
                        msg.latitude if has_fix else math.nan,
                        msg.longitude if has_fix else math.nan,
                        msg.altitude if has_fix else math.nan,
                        acc,
                        3.0 if has_fix else 0.0,
                    ]
                )
            elif calibration is None:
                calibration = _calibration(msg)
    except InvalidInputError:
        raise
    except Exception as exc:
        raise InvalidInputError(source, f"unreadable ROS bag: {exc}") from None
    finally:
        reader.close()
    if not shots:
        raise InvalidInputError(source, f"no message on the image topic {images[0].topic}")
    if attitude_c and not att_t:
        raise InvalidInputError(source, f"no message on the attitude topic {attitude_c[0].topic}")
    if not fix_t:
        raise InvalidInputError(source, f"no message on the NavSatFix topic {navsat_c[0].topic}")
    order = np.argsort(att_t, kind="stable")
    gorder = np.argsort(fix_t, kind="stable")
    shots.sort(key=lambda s: s.t_s or 0.0)
    track = LogTrack(
        source=source,
        kind=KIND,
        attitude=Series.build(
            attitude_c[0].topic,
            np.asarray(att_t)[order],
            np.asarray(att_v)[order],
            (2,),
            source=source,
        )
        if attitude_c
        else None,
        position=None,
        gnss=Series.build(
            navsat_c[0].topic, np.asarray(fix_t)[gorder], np.asarray(fix_v)[gorder], source=source
        ),
        utc_offset_s=0.0,
        notes=(
            f"images {images[0].topic}, attitude "
            + (attitude_c[0].topic if attitude_c else "none")
            + f", position {navsat_c[0].topic}, intrinsics "
            + (info_c[0].topic if info_c else "not recorded"),
            *([] if attitude_c else [NO_ATTITUDE]),
        ),
    )
    return track, shots, calibration
