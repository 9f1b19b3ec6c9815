"""Recorded-flight logs for tests and examples, written with the libraries' own writers over a
rendered flight whose poses are known (a ``c3-flight/1`` dataset such as
``data/flights/naip_demo``): a PX4 ULog (``pyulog``), a MAVLink telemetry log (``pymavlink``),
an ArduPilot DataFlash log (the documented FMT layout, read back by ``pymavlink``), ROS 2 bags
in sqlite3 and MCAP storage (``rosbags``) and photos with EXIF/XMP (``piexif``).

Each log states the frames' true nadir position (``alt_m`` = ``GROUND_M`` + the height above
ground), attitude and capture time; the GNSS time of the first frame is ``UTC0``. Writers take
``flaws`` to make the bad logs the importers must refuse or flag.
"""

from __future__ import annotations

import itertools
import json
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.camera import rotation_world_from_body
from c3_matcher.dto import Attitude

__all__ = [
    "GROUND_M",
    "UTC0",
    "Pose",
    "flight_poses",
    "write_bag",
    "write_dataflash",
    "write_exif_photos",
    "write_tlog",
    "write_ulog",
]

GROUND_M = 500.0
"""The ground's altitude above sea level in every written log (m)."""
UTC0 = 1_790_000_000.0
"""UTC time of the first frame (s)."""
BOOT_S = 100.0
"""Log time (s since boot) of the first frame."""


@dataclass(frozen=True)
class Pose:
    """One frame of a rendered flight: ``t_s`` from the first frame, nadir ``lat``/``lon``,
    ``height_m`` above ground, attitude (deg), ``image`` (path of the frame)."""

    t_s: float
    lat: float
    lon: float
    height_m: float
    roll: float
    pitch: float
    yaw: float
    image: Path

    @property
    def alt_m(self) -> float:
        return GROUND_M + self.height_m

    def quaternion(self) -> tuple[float, float, float, float]:
        """(w, x, y, z) of the body (FRD) to NED rotation."""
        r = rotation_world_from_body(Attitude.from_degrees(self.roll, self.pitch, self.yaw))
        return _quat(r)


def _quat(r: np.ndarray) -> tuple[float, float, float, float]:
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return w, x, y, z


def flight_poses(dataset: Path, frames: Sequence[int]) -> list[Pose]:
    """The poses of ``frames`` of a rendered dataset (its ``frames.jsonl``)."""
    records = [json.loads(x) for x in (Path(dataset) / "frames.jsonl").read_text().splitlines()]
    out = []
    for i in frames:
        f = records[i]
        r, p, y = f["attitude_deg"]
        out.append(
            Pose(
                f["captured_at_ns"] / 1e9,
                f["pose"]["nadir_lat"],
                f["pose"]["nadir_lon"],
                float(f["height_m"]),
                r,
                p,
                y,
                Path(dataset) / f["image"],
            )
        )
    return out


def _dense(poses: Sequence[Pose], rate_hz: float = 5.0) -> list[tuple[float, float, float, float]]:
    """(t, lat, lon, alt) at ``rate_hz`` along the poses, straight between frames."""
    out = []
    for a, b in itertools.pairwise(poses):
        n = max(1, round((b.t_s - a.t_s) * rate_hz))
        for k in range(n):
            w = k / n
            out.append(
                (
                    a.t_s + w * (b.t_s - a.t_s),
                    a.lat + w * (b.lat - a.lat),
                    a.lon + w * (b.lon - a.lon),
                    a.alt_m + w * (b.alt_m - a.alt_m),
                )
            )
    last = poses[-1]
    out.append((last.t_s, last.lat, last.lon, last.alt_m))
    return out


# --- PX4 ULog (pyulog) ---------------------------------------------------------------------


_Topic = tuple[str, list[tuple[str, str]], dict[str, Sequence[Any]]]
"""A ULog topic: its name, (type, field) of each field, and each field's values."""


def write_ulog(
    path: Path, poses: Sequence[Pose], *, flaws: Sequence[str] = (), rangefinder: bool = False
) -> Path:
    """A PX4 ULog with ``vehicle_attitude``, ``vehicle_global_position``,
    ``vehicle_gps_position`` (eph 1.5 m, 3D fix, UTC time), ``home_position`` and
    ``camera_capture`` (one per frame). ``flaws``: ``no_attitude`` (topic left out),
    ``no_trigger``, ``gnss_loss`` (the receiver reports no fix over the second frame);
    ``rangefinder``: ``vehicle_local_position.dist_bottom`` (valid) states the height above
    ground, the ground 20 m higher than home (``home_position.alt``)."""
    from pyulog import ULog

    ulog = ULog(None)
    ulog._file_version = 1
    ulog._start_timestamp = int(BOOT_S * 1e6) - 1_000_000
    us = [int((BOOT_S + p.t_s) * 1e6) for p in poses]
    topics: list[_Topic] = []
    if "no_attitude" not in flaws:
        topics.append(_ulog_attitude(poses, us))
    topics += _ulog_positions(poses, gnss_loss="gnss_loss" in flaws)
    topics += _ulog_heights(poses, us, rangefinder)
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


def _ulog_attitude(poses: Sequence[Pose], us: list[int]) -> _Topic:
    """``vehicle_attitude``: each frame's quaternion at its time ``us`` (µs since boot)."""
    quats = [p.quaternion() for p in poses]
    return (
        "vehicle_attitude",
        [("uint64_t", "timestamp"), ("float[4]", "q")],
        {"timestamp": list(us), **{f"q[{k}]": [q[k] for q in quats] for k in range(4)}},
    )


def _ulog_positions(poses: Sequence[Pose], *, gnss_loss: bool) -> list[_Topic]:
    """``vehicle_global_position`` and ``vehicle_gps_position`` along the poses (``gnss_loss``:
    no fix within 0.3 s of the second frame)."""
    dense = _dense(poses)
    dus = [int((BOOT_S + d[0]) * 1e6) for d in dense]
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
            "time_utc_usec": [int((UTC0 + d[0]) * 1e6) for d in dense],
            "lat": [round(d[1] * 1e7) for d in dense],
            "lon": [round(d[2] * 1e7) for d in dense],
            "alt": [round(d[3] * 1e3) for d in dense],
            "eph": [99.0 if i in lost else 1.5 for i in range(len(dense))],
            "fix_type": [0 if i in lost else 3 for i in range(len(dense))],
        },
    )
    return [estimate, receiver]


def _ulog_heights(poses: Sequence[Pose], us: list[int], rangefinder: bool) -> list[_Topic]:
    """``home_position`` (its altitude the ground's, 20 m lower with a ``rangefinder``) and the
    rangefinder's ``vehicle_local_position`` at each frame's time ``us``."""
    home: _Topic = (
        "home_position",
        [("uint64_t", "timestamp"), ("float", "alt")],
        {"timestamp": [us[0]], "alt": [GROUND_M - (20.0 if rangefinder else 0.0)]},
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
            "ref_alt": [GROUND_M - 20.0] * len(us),
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


# --- MAVLink telemetry log (pymavlink) -------------------------------------------------------


def write_tlog(path: Path, poses: Sequence[Pose], *, flaws: Sequence[str] = ()) -> Path:
    """A ground station's MAVLink telemetry log: ATTITUDE, GLOBAL_POSITION_INT, GPS_RAW_INT
    (h_acc 1.5 m) and CAMERA_FEEDBACK per frame, each prefixed by its UTC time as pymavlink
    writes it. ``flaws``: ``no_attitude``, ``no_trigger``."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    records = _tlog_positions(poses) + _tlog_frames(poses, flaws)
    records.sort(key=lambda r: r[0])
    path = Path(path)
    with path.open("wb") as fh:
        for t, msg in records:
            fh.write(struct.pack(">Q", int((UTC0 + t) * 1e6)) + msg.pack(mav))
    return path


def _tlog_positions(poses: Sequence[Pose]) -> list[tuple[float, Any]]:
    """(t, message) of GLOBAL_POSITION_INT and GPS_RAW_INT (3D fix, h_acc 1.5 m) along the
    poses."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    records: list[tuple[float, Any]] = []
    for t, lat, lon, alt in _dense(poses):
        ms = int((BOOT_S + t) * 1e3)
        rel = int((alt - GROUND_M) * 1e3)
        lat_e7, lon_e7, alt_mm = round(lat * 1e7), round(lon * 1e7), round(alt * 1e3)
        records.append(
            (
                t,
                mavlink.MAVLink_global_position_int_message(
                    ms, lat_e7, lon_e7, alt_mm, rel, 0, 0, 0, 0
                ),
            )
        )
        utc_us = int((UTC0 + t) * 1e6)
        fix = mavlink.MAVLink_gps_raw_int_message(
            utc_us, 3, lat_e7, lon_e7, alt_mm, 80, 120, 0, 0, 12, 0, 1500, 2500, 0, 0, 0
        )
        records.append((t, fix))
    return records


def _tlog_frames(poses: Sequence[Pose], flaws: Sequence[str]) -> list[tuple[float, Any]]:
    """(t, message) of each frame's ATTITUDE and CAMERA_FEEDBACK (``flaws``: ``no_attitude``,
    ``no_trigger`` leave them out)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    records: list[tuple[float, Any]] = []
    for i, p in enumerate(poses):
        ms = int((BOOT_S + p.t_s) * 1e3)
        if "no_attitude" not in flaws:
            roll, pitch, yaw = (math.radians(a) for a in (p.roll, p.pitch, p.yaw))
            records.append((p.t_s, mavlink.MAVLink_attitude_message(ms, roll, pitch, yaw, 0, 0, 0)))
        if "no_trigger" not in flaws:
            utc_us = int((UTC0 + p.t_s) * 1e6)
            lat_e7, lon_e7 = round(p.lat * 1e7), round(p.lon * 1e7)
            feedback = mavlink.MAVLink_camera_feedback_message(
                utc_us, 1, 0, i, lat_e7, lon_e7, p.alt_m, p.height_m, p.roll, p.pitch, p.yaw, 4.5, 0
            )
            records.append((p.t_s, feedback))
    return records


# --- ArduPilot DataFlash (.bin) ---------------------------------------------------------------

_DF_HEAD = b"\xa3\x95"
_DF_FORMATS = {
    # name: (type id, struct format chars, columns)
    "ATT": (1, "Qfff", "TimeUS,Roll,Pitch,Yaw"),
    "POS": (2, "QLLff", "TimeUS,Lat,Lng,Alt,RelHomeAlt"),
    "GPS": (3, "QBIHLLf", "TimeUS,Status,GMS,GWk,Lat,Lng,Alt"),
    "GPA": (4, "Qf", "TimeUS,HAcc"),
    "CAM": (5, "QH", "TimeUS,Img"),
}
_DF_STRUCT = {"Q": "Q", "f": "f", "L": "i", "B": "B", "I": "I", "H": "H"}


def write_dataflash(path: Path, poses: Sequence[Pose], *, flaws: Sequence[str] = ()) -> Path:
    """An ArduPilot DataFlash log in the documented binary layout (FMT messages, then ATT, POS,
    GPS with GNSS week time, GPA and CAM); ``flaws``: ``no_attitude``, ``no_trigger``,
    ``time_jump`` (the middle frame's ATT stamped 5 s before the frame before it)."""
    out = bytearray()

    def fmt_message(type_id: int, name: str, fmt: str, cols: str) -> bytes:
        length = 3 + struct.calcsize("<" + "".join(_DF_STRUCT[c] for c in fmt))
        return (
            _DF_HEAD
            + bytes([128])
            + struct.pack(
                "<BB4s16s64s", type_id, length, name.encode(), fmt.encode(), cols.encode()
            )
        )

    out += (
        _DF_HEAD
        + bytes([128])
        + struct.pack("<BB4s16s64s", 128, 89, b"FMT", b"BBnNZ", b"Type,Length,Name,Format,Columns")
    )
    for name, (type_id, fmt, cols) in _DF_FORMATS.items():
        out += fmt_message(type_id, name, fmt, cols)

    def msg(name: str, *values: Any) -> tuple[int, bytes]:
        type_id, fmt, _ = _DF_FORMATS[name]
        body = struct.pack("<" + "".join(_DF_STRUCT[c] for c in fmt), *values)
        return values[0], _DF_HEAD + bytes([type_id]) + body

    gps_epoch = 315_964_800.0  # 1980-01-06 UTC
    leap = 18.0
    items: list[tuple[int, bytes]] = []
    for t, lat, lon, alt in _dense(poses):
        tus = int((BOOT_S + t) * 1e6)
        gps_s = UTC0 + t - gps_epoch + leap
        week, ms = int(gps_s // 604800), round((gps_s % 604800) * 1e3)
        items.append(msg("POS", tus, round(lat * 1e7), round(lon * 1e7), alt, alt - GROUND_M))
        items.append(msg("GPS", tus, 3, ms, week, round(lat * 1e7), round(lon * 1e7), alt))
        items.append(msg("GPA", tus, 1.5))
    for i, p in enumerate(poses):
        tus = int((BOOT_S + p.t_s) * 1e6)
        if "no_attitude" not in flaws:
            att = msg("ATT", tus, p.roll, p.pitch, p.yaw % 360.0)
            if "time_jump" in flaws and i == len(poses) // 2:
                back = int((BOOT_S + poses[i - 1].t_s - 5.0) * 1e6)
                att = (tus, msg("ATT", back, p.roll, p.pitch, p.yaw % 360.0)[1])
            items.append(att)
        if "no_trigger" not in flaws:
            items.append(msg("CAM", tus, i))
    items.sort(key=lambda x: x[0])
    for _, data in items:
        out += data
    path = Path(path)
    path.write_bytes(bytes(out))
    return path


# --- ROS 2 bags (rosbags) ---------------------------------------------------------------------


def write_bag(
    path: Path,
    poses: Sequence[Pose],
    calibration: Any,
    *,
    storage: str = "sqlite3",
    compressed: bool = True,
    flaws: Sequence[str] = (),
    pose_topic: bool = False,
) -> Path:
    """A ROS 2 bag (``storage`` sqlite3 or mcap) with ``/camera/image_raw/compressed``
    (``sensor_msgs/CompressedImage``; ``sensor_msgs/Image`` rgb8 when not ``compressed``),
    ``/camera/camera_info``, ``/imu/data`` (``sensor_msgs/Imu``, ENU / FLU as REP 103 says) and
    ``/gps/fix`` (``sensor_msgs/NavSatFix``, covariance 1.5 m); ``pose_topic``: the same
    orientation also on ``/vehicle/pose`` (``geometry_msgs/PoseStamped``). ``flaws``:
    ``no_imu``, ``no_gps``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    path = Path(path)
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conns = _bag_connections(writer, store, compressed, flaws, pose_topic)
        msgs = _bag_frame_messages(
            store.types, poses, calibration.image_size, compressed, flaws, pose_topic
        )
        info_t = poses[0].t_s - 0.5
        msgs.append((info_t, "info", _camera_info(store.types, calibration, info_t)))
        if "no_gps" not in flaws:
            msgs += _gps_fixes(store.types, poses)
        msgs.sort(key=lambda x: (x[0], x[1]))
        for t, key, msg in msgs:
            writer.write(conns[key], _utc_ns(t), store.serialize_cdr(msg, msg.__msgtype__))
    return path


def _utc_ns(t: float) -> int:
    """The UTC time in ns of log time ``t`` (s from the first frame)."""
    return round((UTC0 + t) * 1e9)


def _ros_header(types: Any, t: float, frame: str) -> Any:
    """A ``std_msgs/Header`` stamped with the UTC time of log time ``t``, in ``frame``."""
    ns = _utc_ns(t)
    stamp = types["builtin_interfaces/msg/Time"](
        sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000
    )
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _bag_connections(
    writer: Any, store: Any, compressed: bool, flaws: Sequence[str], pose_topic: bool
) -> dict[str, Any]:
    """The bag's topics by message key: the images (``compressed`` or raw), the camera info,
    then the IMU (unless ``no_imu``), the pose (``pose_topic``) and the fix (unless
    ``no_gps``)."""
    image_topic = "/camera/image_raw/compressed" if compressed else "/camera/image_raw"
    image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    conns = {
        "image": writer.add_connection(image_topic, image_type, typestore=store),
        "info": writer.add_connection(
            "/camera/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store
        ),
    }
    if "no_imu" not in flaws:
        conns["imu"] = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
    if pose_topic:
        conns["pose"] = writer.add_connection(
            "/vehicle/pose", "geometry_msgs/msg/PoseStamped", typestore=store
        )
    if "no_gps" not in flaws:
        conns["gps"] = writer.add_connection(
            "/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=store
        )
    return conns


def _bag_frame_messages(
    types: Any,
    poses: Sequence[Pose],
    size: tuple[int, int],
    compressed: bool,
    flaws: Sequence[str],
    pose_topic: bool,
) -> list[tuple[float, str, Any]]:
    """(t, key, message) of each frame's image, its IMU orientation (unless ``no_imu``) and
    pose (``pose_topic``)."""
    msgs: list[tuple[float, str, Any]] = []
    for p in poses:
        msgs.append((p.t_s, "image", _image_message(types, p, size, compressed)))
        qw, qx, qy, qz = _ros_orientation(p)
        orientation = types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
        if "no_imu" not in flaws:
            vector = types["geometry_msgs/msg/Vector3"]
            imu = types["sensor_msgs/msg/Imu"](
                header=_ros_header(types, p.t_s, "base_link"),
                orientation=orientation,
                orientation_covariance=np.zeros(9),
                angular_velocity=vector(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vector(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=np.zeros(9),
            )
            msgs.append((p.t_s, "imu", imu))
        if pose_topic:
            pose = types["geometry_msgs/msg/PoseStamped"](
                header=_ros_header(types, p.t_s, "map"),
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=p.height_m),
                    orientation=orientation,
                ),
            )
            msgs.append((p.t_s, "pose", pose))
    return msgs


def _ros_orientation(p: Pose) -> tuple[float, float, float, float]:
    """(w, x, y, z) of frame ``p``'s body (FLU) to ENU rotation, as REP 103 states it."""
    enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    frd_from_flu = np.diag([1.0, -1.0, -1.0])
    r_ned_frd = rotation_world_from_body(Attitude.from_degrees(p.roll, p.pitch, p.yaw))
    return _quat(enu_from_ned @ r_ned_frd @ frd_from_flu)


def _image_message(types: Any, p: Pose, size: tuple[int, int], compressed: bool) -> Any:
    """Frame ``p``'s image: its JPEG as it is (``compressed``), else decoded to rgb8 of
    ``size`` (w, h)."""
    import cv2

    data = p.image.read_bytes()
    header = _ros_header(types, p.t_s, "camera")
    if compressed:
        return types["sensor_msgs/msg/CompressedImage"](
            header=header, format="jpeg", data=np.frombuffer(data, np.uint8)
        )
    w, h = size
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return types["sensor_msgs/msg/Image"](
        header=header,
        height=h,
        width=w,
        encoding="rgb8",
        is_bigendian=0,
        step=w * 3,
        data=cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).reshape(-1),
    )


def _camera_info(types: Any, calibration: Any, t: float) -> Any:
    """A ``sensor_msgs/CameraInfo`` (plumb_bob) of ``calibration`` at log time ``t``."""
    k = np.asarray(calibration.K, dtype=np.float64)
    w, h = calibration.image_size
    return types["sensor_msgs/msg/CameraInfo"](
        header=_ros_header(types, t, "camera"),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        d=np.asarray(calibration.distortion, dtype=np.float64),
        k=k.reshape(-1),
        r=np.eye(3).reshape(-1),
        p=np.hstack([k, np.zeros((3, 1))]).reshape(-1),
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def _gps_fixes(types: Any, poses: Sequence[Pose]) -> list[tuple[float, str, Any]]:
    """(t, "gps", fix) along the poses: ``sensor_msgs/NavSatFix``, 1.5 m horizontal and 3 m
    vertical standard deviation."""
    fixes: list[tuple[float, str, Any]] = []
    for t, lat, lon, alt in _dense(poses):
        fix = types["sensor_msgs/msg/NavSatFix"](
            header=_ros_header(types, t, "gps"),
            status=types["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=lat,
            longitude=lon,
            altitude=alt,
            position_covariance=np.diag([2.25, 2.25, 9.0]).reshape(-1),
            position_covariance_type=2,
        )
        fixes.append((t, "gps", fix))
    return fixes


# --- photos with EXIF / XMP (piexif) ----------------------------------------------------------


def _rational(value: float, den: int = 10_000) -> tuple[int, int]:
    return round(value * den), den


def _dms(value: float) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int]]:
    value = abs(value)
    d = int(value)
    m = int((value - d) * 60)
    s = (value - d - m / 60) * 3600
    return (d, 1), (m, 1), _rational(s, 100_000)


def write_exif_photos(
    folder: Path, poses: Sequence[Pose], *, names: str = "DJI_{:04d}.JPG", xmp: bool = True
) -> Path:
    """The frames as JPEG photos carrying what a survey drone writes: EXIF capture time (UTC,
    with sub-seconds), GPS latitude/longitude/altitude above sea level, and (``xmp``) an XMP
    packet with ``drone-dji:RelativeAltitude`` and the gimbal's roll/pitch/yaw of the camera's
    pointing (pitch -90 = straight down)."""
    import datetime

    import piexif

    from c3_matcher.camera import DEFAULT_BODY_FROM_CAMERA
    from c3_matcher_tools.dataset.sources.track import attitude_from_matrix

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    forward_from_camera = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    for i, p in enumerate(poses):
        when = datetime.datetime.fromtimestamp(UTC0 + p.t_s, datetime.UTC)
        exif = {
            "0th": {},
            "Exif": {
                piexif.ExifIFD.DateTimeOriginal: when.strftime("%Y:%m:%d %H:%M:%S").encode(),
                piexif.ExifIFD.SubSecTimeOriginal: f"{when.microsecond // 1000:03d}".encode(),
            },
            "GPS": {
                piexif.GPSIFD.GPSLatitudeRef: b"N" if p.lat >= 0 else b"S",
                piexif.GPSIFD.GPSLatitude: _dms(p.lat),
                piexif.GPSIFD.GPSLongitudeRef: b"E" if p.lon >= 0 else b"W",
                piexif.GPSIFD.GPSLongitude: _dms(p.lon),
                piexif.GPSIFD.GPSAltitudeRef: 0,
                piexif.GPSIFD.GPSAltitude: _rational(p.alt_m, 1000),
            },
        }
        data = p.image.read_bytes()
        target = folder / names.format(i)
        piexif.insert(piexif.dump(exif), data, str(target))
        if xmp:
            r_cam = (
                rotation_world_from_body(Attitude.from_degrees(p.roll, p.pitch, p.yaw))
                @ DEFAULT_BODY_FROM_CAMERA
            )
            g_roll, g_pitch, g_yaw = attitude_from_matrix(r_cam @ forward_from_camera.T)
            packet = (
                '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF '
                'xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
                '<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
                f'drone-dji:RelativeAltitude="+{p.height_m:.3f}" '
                f'drone-dji:GimbalRollDegree="{g_roll:+.4f}" '
                f'drone-dji:GimbalPitchDegree="{g_pitch:+.4f}" '
                f'drone-dji:GimbalYawDegree="{g_yaw:+.4f}"/></rdf:RDF></x:xmpmeta>'
            ).encode()
            head = b"http://ns.adobe.com/xap/1.0/\x00" + packet
            jpeg = target.read_bytes()
            segment = b"\xff\xe1" + struct.pack(">H", len(head) + 2) + head
            target.write_bytes(jpeg[:2] + segment + jpeg[2:])
    return folder
