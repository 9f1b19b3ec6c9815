"""ROS bags of a rendered flight, written with ``rosbags``: ROS 2 (sqlite3 or MCAP storage) or
ROS 1 (a ``.bag`` of ROS 1 Noetic's message types, ``CameraInfo.D`` / ``K`` spelt so)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.camera import rotation_world_from_body
from c3_matcher.dto import Attitude
from c3_matcher_tools.testing.flightlogs import UTC0, Pose, dense_track, quaternion_wxyz

__all__ = ["GEOID_HEIGHT_M", "write_bag"]

GEOID_HEIGHT_M = -15.0
"""The geoid height the bags are written with by default (sea level this far above the WGS84
ellipsoid, m): their NavSatFix altitude is above the ellipsoid, as the message defines it,
``GROUND_M`` + the height + this; not 0, so that a reader taking it for sea level is off."""


def write_bag(
    path: Path,
    poses: Sequence[Pose],
    calibration: Any,
    *,
    storage: str = "sqlite3",
    compressed: bool = True,
    flaws: Sequence[str] = (),
    pose_topic: bool = False,
    geoid_height_m: float = GEOID_HEIGHT_M,
) -> Path:
    """A ROS 2 bag (``storage`` sqlite3 or mcap; ``ros1``: a ROS 1 ``.bag`` file) with
    ``/camera/image_raw/compressed``
    (``sensor_msgs/CompressedImage``; ``sensor_msgs/Image`` rgb8 when not ``compressed``),
    ``/camera/camera_info``, ``/imu/data`` (``sensor_msgs/Imu``, ENU / FLU as REP 103 says) and
    ``/gps/fix`` (``sensor_msgs/NavSatFix``, covariance 1.5 m, altitude above the WGS84
    ellipsoid as the message defines it: above sea level + ``geoid_height_m``, sea level's
    height above the ellipsoid there; 0 writes sea-level altitude, as some drivers do);
    ``pose_topic``: the same
    orientation also on ``/vehicle/pose`` (``geometry_msgs/PoseStamped``). ``flaws``:
    ``no_imu``, ``no_gps``."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = storage == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    path = Path(path)
    with _writer(path, storage) as writer:
        conns = _bag_connections(writer, store, compressed, flaws, pose_topic)
        msgs = _bag_frame_messages(
            store.types, poses, calibration.image_size, compressed, flaws, pose_topic
        )
        info_t = poses[0].t_s - 0.5
        msgs.append((info_t, "info", _camera_info(store.types, calibration, info_t)))
        if "no_gps" not in flaws:
            msgs += _gps_fixes(store.types, poses, geoid_height_m)
        msgs.sort(key=lambda x: (x[0], x[1]))
        for t, key, msg in msgs:
            writer.write(conns[key], _utc_ns(t), serialize(msg, msg.__msgtype__))
    return path


def _writer(path: Path, storage: str) -> Any:
    """The bag's writer: ROS 1 (``ros1``) or ROS 2 in ``storage`` (sqlite3 or mcap)."""
    if storage == "ros1":
        from rosbags.rosbag1 import Writer as Ros1Writer

        return Ros1Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer(path, version=8, storage_plugin=plugin)


def _ros1(types: Any) -> bool:
    """Whether ``types`` are ROS 1's (its Header has a ``seq``)."""
    return "seq" in types["std_msgs/msg/Header"].__dataclass_fields__


def _utc_ns(t: float) -> int:
    """The UTC time in ns of log time ``t`` (s from the first frame)."""
    return round((UTC0 + t) * 1e9)


def _ros_header(types: Any, t: float, frame: str) -> Any:
    """A ``std_msgs/Header`` stamped with the UTC time of log time ``t``, in ``frame``."""
    ns = _utc_ns(t)
    stamp = types["builtin_interfaces/msg/Time"](
        sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000
    )
    seq = {"seq": 0} if _ros1(types) else {}
    return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **seq)


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
    return quaternion_wxyz(enu_from_ned @ r_ned_frd @ frd_from_flu)


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
    """A ``sensor_msgs/CameraInfo`` (plumb_bob) of ``calibration`` at log time ``t`` (its
    matrices ``D``, ``K``, ``R``, ``P`` in ROS 1, ``d``, ``k``, ``r``, ``p`` in ROS 2)."""
    k = np.asarray(calibration.K, dtype=np.float64)
    w, h = calibration.image_size
    matrices = {
        "d": np.asarray(calibration.distortion, dtype=np.float64),
        "k": k.reshape(-1),
        "r": np.eye(3).reshape(-1),
        "p": np.hstack([k, np.zeros((3, 1))]).reshape(-1),
    }
    ros1 = _ros1(types)
    return types["sensor_msgs/msg/CameraInfo"](
        header=_ros_header(types, t, "camera"),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        **{(name.upper() if ros1 else name): value for name, value in matrices.items()},
        binning_x=0,
        binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )


def _gps_fixes(
    types: Any, poses: Sequence[Pose], geoid_height_m: float = GEOID_HEIGHT_M
) -> list[tuple[float, str, Any]]:
    """(t, "gps", fix) along the poses: ``sensor_msgs/NavSatFix``, 1.5 m horizontal and 3 m
    vertical standard deviation, its altitude above the ellipsoid (sea level's +
    ``geoid_height_m``)."""
    fixes: list[tuple[float, str, Any]] = []
    for t, lat, lon, alt in dense_track(poses):
        fix = types["sensor_msgs/msg/NavSatFix"](
            header=_ros_header(types, t, "gps"),
            status=types["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=lat,
            longitude=lon,
            altitude=alt + geoid_height_m,
            position_covariance=np.diag([2.25, 2.25, 9.0]).reshape(-1),
            position_covariance_type=2,
        )
        fixes.append((t, "gps", fix))
    return fixes
